"""A front's copy of the fleet, slot by slot: pure bookkeeping, no broker."""

from __future__ import annotations

from typing import Any

from kybercore.scale.follow import STALE_SECONDS, FleetCopy, WorkerSeen, silent_owner
from kybercore.scale.slots import SlotRef

S = [SlotRef("", n) for n in range(4)]


def batch(epoch: int, seq: int, **patches: Any) -> dict[str, Any]:
    return {"epoch": epoch, "seq": seq, "patches": patches, "removed": [], "events": []}


Patch = tuple[str, dict[str, Any], dict[str, Any]]


def copy(patched: list[Patch] | None = None) -> tuple[FleetCopy, list[str]]:
    changed: list[str] = []
    passed = [] if patched is None else patched

    def on_patch(printer_id: str, view: dict[str, Any], patch: dict[str, Any]) -> None:
        passed.append((printer_id, view, patch))

    return FleetCopy(changed.append, on_patch, lambda _e: None), changed


def test_batches_wait_for_a_snapshot_then_apply_in_order() -> None:
    patched: list[Patch] = []
    fleet, changed = copy(patched)
    assert fleet.batch(S[1], batch(7, 5, p={"x": 5}), now=0.0)  # new epoch: snapshot please
    assert not fleet.batch(S[1], batch(7, 6, p={"x": 6}), now=0.1)
    assert not fleet.snapshot(S[1], {"epoch": 7, "seq": 5, "views": {"p": {"x": 5, "y": 1}}}, 0.2)
    assert fleet.views["p"] == {"x": 6, "y": 1}  # seq 5 was in the snapshot, 6 applied after
    assert not fleet.batch(S[1], batch(7, 7, p={"y": 2}), now=0.3)
    assert fleet.views["p"] == {"x": 6, "y": 2}
    # The snapshot is rendered again; each patch after it is passed on as the worker sent it.
    assert changed == ["p"]
    assert patched == [("p", {"x": 6, "y": 1}, {"x": 6}), ("p", {"x": 6, "y": 2}, {"y": 2})]


def test_a_gap_asks_for_a_snapshot_and_an_older_epoch_is_ignored() -> None:
    fleet, _ = copy()
    fleet.batch(S[0], batch(3, 1), now=0.0)
    fleet.snapshot(S[0], {"epoch": 3, "seq": 1, "views": {"p": {"x": 1}}}, 0.0)
    assert fleet.batch(S[0], batch(3, 3, p={"x": 3}), now=0.1)  # seq 2 went missing
    assert fleet.views["p"] == {"x": 1}
    assert not fleet.batch(S[0], batch(2, 9, p={"x": 99}), now=0.2)  # a paused old owner
    fleet.snapshot(S[0], {"epoch": 3, "seq": 3, "views": {"p": {"x": 3}}}, 0.3)
    assert not fleet.batch(S[0], batch(2, 10, p={"x": 99}), now=0.4)
    assert fleet.views["p"] == {"x": 3}


def test_a_silent_slot_goes_stale_and_comes_back() -> None:
    fleet, changed = copy()
    fleet.batch(S[2], batch(1, 1), now=0.0)
    fleet.snapshot(S[2], {"epoch": 1, "seq": 1, "views": {"p": {"x": 1}}}, 0.0)
    assert fleet.check(now=1.0) == []
    assert not fleet.is_stale(S[2])
    changed.clear()
    fleet.check(now=STALE_SECONDS + 0.5)
    assert fleet.is_stale(S[2])
    assert changed == ["p"]  # redrawn as stale
    fleet.batch(S[2], batch(1, 1), now=STALE_SECONDS + 1)  # a heartbeat
    fleet.check(now=STALE_SECONDS + 1)
    assert not fleet.is_stale(S[2])


def test_each_worker_is_seen_by_its_fresh_slots_and_its_latest_loop_lag() -> None:
    fleet, _ = copy()

    def said(slot: int, worker: str, lag: float, now: float) -> None:
        fleet.batch(S[slot], {**batch(1, 1), "worker": worker, "lag": lag}, now=now)

    said(0, "w1", 0.01, now=0.0)
    said(1, "w1", 0.4, now=0.5)  # w1's latest word
    said(2, "w2", 0.02, now=0.0)
    fleet.check(now=1.0)
    assert fleet.workers() == {"w1": WorkerSeen(2, 0.4), "w2": WorkerSeen(1, 0.02)}
    # w2 goes silent; w1 takes its slot over and is heard again, on time now.
    fleet.check(now=STALE_SECONDS + 0.4)
    said(2, "w1", 0.0, now=STALE_SECONDS + 0.5)
    said(0, "w1", 0.0, now=STALE_SECONDS + 0.5)
    fleet.check(now=STALE_SECONDS + 0.6)
    assert fleet.workers() == {"w1": WorkerSeen(2, 0.0)}  # slot 1 went stale meanwhile
    # A snapshot says who answered it, too.
    fleet.snapshot(S[3], {"epoch": 1, "seq": 1, "worker": "w3", "lag": 1.5, "views": {}}, 3.0)
    fleet.check(now=3.0)
    assert fleet.workers()["w3"] == WorkerSeen(1, 1.5)


def test_the_same_slot_number_of_two_sites_is_two_slots() -> None:
    fleet, _ = copy()
    lab, home = SlotRef("lab", 1), S[1]
    fleet.batch(lab, batch(4, 1), now=0.0)
    fleet.snapshot(lab, {"epoch": 4, "seq": 1, "views": {"a": {"x": 1}}}, 0.0)
    assert fleet.is_stale(home)
    assert not fleet.heard(home)  # nobody holds the default site's
    assert (fleet.epoch(lab), fleet.epoch(home)) == (4, 0)
    assert fleet.batch(home, batch(9, 1, b={"x": 2}), now=0.1)  # its own epoch: snapshot
    fleet.snapshot(home, {"epoch": 9, "seq": 1, "views": {"b": {"x": 2}}}, 0.1)
    assert fleet.views == {"a": {"x": 1}, "b": {"x": 2}}
    assert fleet.check(now=1.0) == []


def test_a_printer_moved_to_another_site_stays_when_its_old_slot_removes_it_late() -> None:
    fleet, changed = copy()
    old, new = S[1], SlotRef("lab", 1)
    fleet.batch(old, batch(1, 1), now=0.0)
    fleet.snapshot(old, {"epoch": 1, "seq": 1, "views": {"p": {"x": 1}}}, 0.0)
    fleet.batch(new, batch(1, 1), now=0.0)
    fleet.snapshot(new, {"epoch": 1, "seq": 1, "views": {}}, 0.0)
    # The new site's worker reports it before the old one's removal arrives.
    fleet.batch(new, batch(1, 2, p={"x": 2}), now=0.1)
    fleet.batch(old, {**batch(1, 2), "removed": ["p"]}, now=0.2)
    assert fleet.views == {"p": {"x": 2}}
    assert fleet.members == {old: set(), new: {"p"}}
    # Its new slot going stale marks it; the old one's does not.
    changed.clear()
    fleet.batch(new, batch(1, 2), now=STALE_SECONDS)
    fleet.check(now=STALE_SECONDS + 0.5)
    assert changed == ["p"]
    assert fleet.is_stale(old)
    assert not fleet.is_stale(new)
    # Removed by the slot that holds it, it is gone.
    fleet.batch(new, {**batch(1, 3), "removed": ["p"]}, now=STALE_SECONDS + 0.6)
    assert fleet.views == {}


def test_a_silent_owner_of_a_site_may_be_a_site_cut_off() -> None:
    # A site keeping its leases at its own leaf node is not taken over while cut off: its
    # printers must not promise that another worker takes them over.
    said = silent_owner("lab-b")
    assert "site 'lab-b' may be cut off" in said
    assert "another worker of site 'lab-b' then takes it over shortly, if one runs" in said
    assert "cut off" not in silent_owner("")
    assert f"over {STALE_SECONDS:.0f} s" in silent_owner("")
