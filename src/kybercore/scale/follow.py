"""A front's copy of the fleet's live views, followed slot by slot from the workers' patches.

Pure bookkeeping, no I/O: the front (:mod:`.front`) feeds it the patch batches and
snapshots it receives and asks it which slots need a snapshot and which are stale.

Per slot (of a site: :class:`~.slots.SlotRef`): patches of an older epoch are from an owner
that lost the slot (paused, cut off): ignored. A newer epoch, or a gap in the sequence,
means the copy may have missed something: the slot waits for a snapshot (patches arriving
meanwhile are kept and applied after it, those the snapshot already holds skipped). A slot
silent for :data:`STALE_SECONDS` (no patch, no heartbeat) is stale: its printers are shown as such.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

from kybercore.core.view import View
from kybercore.moonraker.objects import merge_status
from kybercore.scale.slots import SlotRef

STALE_SECONDS: Final = 2.0


def silent_owner(site: str) -> str:
    """What a printer of a stale slot says while its front still has the broker: its
    owner may have stopped, or (a site's) be cut off from this front's NATS, with its
    leases held at its own leaf node so that nobody takes over."""
    silent = (
        f"No news from the KyberCore worker holding this printer for over {STALE_SECONDS:.0f} s"
    )
    if site:
        return (
            f"{silent}: it may have stopped (another worker of site '{site}' then takes it "
            f"over shortly, if one runs), or site '{site}' may be cut off from this server."
        )
    return f"{silent}; another worker takes it over shortly, if one runs."


@dataclass
class SlotCopy:
    """What the front knows of one slot."""

    epoch: int = 0
    seq: int = 0
    heard: float = -1e9
    """monotonic() of the last batch or heartbeat."""
    synced: bool = False
    """A snapshot of this epoch was applied, and no gap since."""
    waiting: list[dict[str, Any]] = field(default_factory=list)
    """Batches received while waiting for a snapshot."""
    stale: bool = True
    worker: str = ""
    """The owner that last spoke for the slot (its batches, heartbeats and snapshots)."""
    lag: float = 0.0
    """How late that owner's event loop was, as its last message said."""


@dataclass(frozen=True)
class WorkerSeen:
    """A worker as a front sees it through the slots it reports."""

    slots: int
    """Fresh slots it reports."""
    loop_lag: float
    """How late its event loop was, by its latest message (seconds)."""


Changed = Callable[[str], None]
"""Told the id of every printer whose view changed (to render it again)."""
Patched = Callable[[str, View, dict[str, Any]], None]
"""Told a printer's new view and the patch that made it from the last one (to pass on)."""


class FleetCopy:
    """Every printer's last view as its owner published it, by slot (of every site)."""

    def __init__(
        self,
        changed: Changed,
        patched: Patched,
        event: Callable[[dict[str, Any]], None],
    ) -> None:
        """A snapshot's views and a slot's staleness reach ``changed``; a batch's patches
        reach ``patched`` as they are."""
        self.slots: dict[SlotRef, SlotCopy] = {}
        """The slots heard from (a slot never heard is stale)."""
        self.views: dict[str, View] = {}
        self._changed = changed
        self._patched = patched
        self._event = event
        self.members: dict[SlotRef, set[str]] = {}
        """Printers last seen in each slot (to mark them when the slot goes stale)."""
        self._home: dict[str, SlotRef] = {}
        """The slot that last reported each printer: a printer moved to another site is
        removed from its old slot, maybe after its new one reported it."""

    def batch(self, slot: SlotRef, body: dict[str, Any], now: float) -> bool:
        """Take a patch batch (or heartbeat); True when the slot needs a snapshot now."""
        copy = self.slots.setdefault(slot, SlotCopy())
        epoch, seq = int(body["epoch"]), int(body["seq"])
        if epoch < copy.epoch:
            return False
        copy.heard = now
        _heard_from(copy, body)
        if epoch > copy.epoch:
            copy.epoch, copy.synced, copy.waiting = epoch, False, [body]
            return True
        if not copy.synced:
            copy.waiting.append(body)
            return False
        if seq <= copy.seq:
            return False  # a heartbeat, or a batch the snapshot held
        if seq == copy.seq + 1:
            self._apply(slot, body)
            return False
        copy.synced, copy.waiting = False, [body]
        return True

    def snapshot(self, slot: SlotRef, body: dict[str, Any], now: float) -> bool:
        """Take a slot's snapshot; True when it is still not in step (ask again)."""
        copy = self.slots.setdefault(slot, SlotCopy())
        epoch = int(body["epoch"])
        if epoch < copy.epoch:
            return True
        copy.epoch, copy.seq, copy.synced, copy.heard = epoch, int(body["seq"]), True, now
        _heard_from(copy, body)
        for printer_id, view in body["views"].items():
            self._take(slot, printer_id, view)
            self._changed(printer_id)
        waiting, copy.waiting = copy.waiting, []
        for batch in sorted(waiting, key=lambda b: int(b["seq"])):
            if int(batch["epoch"]) != epoch or int(batch["seq"]) <= copy.seq:
                continue
            if int(batch["seq"]) != copy.seq + 1:
                copy.synced, copy.waiting = False, [batch]
                return True
            self._apply(slot, batch)
        return False

    def _take(self, slot: SlotRef, printer_id: str, view: View) -> None:
        self.views[printer_id] = view
        before = self._home.get(printer_id)
        if before != slot:
            if before is not None:
                self.members[before].discard(printer_id)
            self._home[printer_id] = slot
            self.members.setdefault(slot, set()).add(printer_id)

    def _apply(self, slot: SlotRef, body: dict[str, Any]) -> None:
        copy = self.slots[slot]
        copy.seq = int(body["seq"])
        for printer_id, patch in body["patches"].items():
            old = self.views.get(printer_id)
            view = patch if old is None else merge_status(old, patch)
            self._take(slot, printer_id, view)
            self._patched(printer_id, view, patch)
        for printer_id in body["removed"]:
            self.members.get(slot, set()).discard(printer_id)
            if self._home.get(printer_id, slot) != slot:
                continue  # moved: its new slot holds it now
            self._home.pop(printer_id, None)
            self.views.pop(printer_id, None)
            self._changed(printer_id)
        for event in body["events"]:
            self._event(event)

    def check(self, now: float) -> list[SlotRef]:
        """Mark slots stale or fresh by their last news; the slots needing a snapshot
        (not in step, and heard from, so that someone owns them)."""
        for slot, copy in self.slots.items():
            stale = now - copy.heard > STALE_SECONDS
            if stale != copy.stale:
                copy.stale = stale
                for printer_id in self.members.get(slot, ()):
                    self._changed(printer_id)
        return [slot for slot, copy in self.slots.items() if not copy.synced and not copy.stale]

    def is_stale(self, slot: SlotRef) -> bool:
        """Whether the slot's owner has been silent too long (or was never heard)."""
        copy = self.slots.get(slot)
        return copy is None or copy.stale

    def heard(self, slot: SlotRef) -> bool:
        """Whether any owner of the slot was ever heard from."""
        return slot in self.slots

    def epoch(self, slot: SlotRef) -> int:
        """The slot's epoch as last heard (0: never)."""
        copy = self.slots.get(slot)
        return 0 if copy is None else copy.epoch

    def workers(self) -> dict[str, WorkerSeen]:
        """The workers reporting fresh slots now: how many each, and its loop's lag."""
        latest: dict[str, SlotCopy] = {}
        counts: dict[str, int] = {}
        for copy in self.slots.values():
            if copy.stale or not copy.worker:
                continue
            counts[copy.worker] = counts.get(copy.worker, 0) + 1
            if copy.worker not in latest or copy.heard > latest[copy.worker].heard:
                latest[copy.worker] = copy
        return {w: WorkerSeen(counts[w], latest[w].lag) for w in sorted(counts)}


def _heard_from(copy: SlotCopy, body: dict[str, Any]) -> None:
    copy.worker = str(body.get("worker", ""))
    copy.lag = float(body.get("lag", 0.0))
