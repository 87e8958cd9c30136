"""``kybercore front``: the fleet as a front sees it on NATS. No printer sockets.

A :class:`FrontFleet` is the :class:`FleetService` the HTTP API and ``/ws`` use, with the
printers held by workers:

- the views are followed from the workers' patch batches (:mod:`.follow`) and published to
  browsers by the same :class:`Hub` as in one process;
- the configuration comes from the ``kc_registry`` bucket (:mod:`.registry`); adding,
  editing and removing a printer write there, and the workers follow;
- actions, dry runs, file lists and the console history go to the printer's owner as
  commands (:mod:`.commands`): the owner validates against live state and answers;
- an uploaded file crosses in the ``kc_uploads`` object store, in chunks, and one command
  has the owner upload (and start) it (:mod:`.uploads`);
- the reads that need the printer's Moonraker or its worker's memory are commands too: the
  macros, the print's objects, the temperature graph, a file's thumbnail, the webcam list
  and a webcam's snapshot (images in base64, refused with ``too_large_for_front`` above
  :data:`~kybercore.scale.wire.MAX_IMAGE`: one NATS message must carry them);
- a webcam's live MJPEG stream is relayed by the printer's owner, chunk by chunk, for as
  long as the browser reads it (:mod:`.streams`).
- the job queue's printers (:mod:`.queue`) are read from these views (:meth:`FrontFleet.watch`
  tells of each change), and what the queue does on a printer goes to its owner as commands.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, BinaryIO, Final

import httpx
from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import NoRespondersError
from nats.errors import TimeoutError as NatsTimeout

from kybercore.aio import cancel_and_wait
from kybercore.core.macros import Macro
from kybercore.core.validation import Verdict
from kybercore.core.view import LivePrinter, View, fuse
from kybercore.errors import UnknownPrinter, not_on_front
from kybercore.fleet.actions import ActionOutcome
from kybercore.fleet.images import Image
from kybercore.fleet.service import FleetService
from kybercore.fleet.temperatures import Series
from kybercore.fleet.webcams import CameraStream, Webcam
from kybercore.moonraker.client import MoonrakerClient
from kybercore.registry.models import PrinterConfig, PrinterCreate, PrinterUpdate
from kybercore.registry.store import PrinterRegistry, read_printers
from kybercore.scale.broker import connect
from kybercore.scale.commands import send_command
from kybercore.scale.cut_off import STALE_MESSAGE, CutOff
from kybercore.scale.follow import FleetCopy, silent_owner
from kybercore.scale.registry import KvRegistry
from kybercore.scale.slots import SlotRef, slot_of
from kybercore.scale.streams import open_stream
from kybercore.scale.uploads import send_upload
from kybercore.scale.wire import (
    decode_image,
    decode_macros,
    decode_outcome,
    decode_verdict,
    decode_webcams,
    loads,
    patch_subject,
    slot_of_subject,
)
from kybercore.scale.wire import snapshot_subject as snap_subject

log = logging.getLogger(__name__)

CHECK_SECONDS: Final = 0.25
SNAPSHOT_TIMEOUT: Final = 2.0

Watcher = Callable[[str, dict[str, Any] | None], None]
"""Told ``(printer id, patch)`` for each patch applied to a printer's view, and
``(printer id, None)`` when its whole view may have changed (a snapshot, its slot going
stale or fresh, a registry change, its removal)."""


class FrontFleet(FleetService):
    """The fleet on NATS, seen from a front; see the module docstring."""

    def __init__(
        self,
        nats_url: str,
        http: httpx.AsyncClient,
        *,
        slots: int,
        printers_file: Path,
        **options: Any,
    ) -> None:
        """``printers_file`` is imported into an empty registry bucket at start."""
        super().__init__(PrinterRegistry(printers_file), http, **options)
        self._url = nats_url
        self._connection: Client | None = None
        self._slots = slots
        self._printers_file = printers_file
        self.kv = KvRegistry()
        self._configs: dict[str, PrinterConfig] = {}
        self._unreported: dict[str, tuple[PrinterConfig, View]] = {}
        """Each printer's view until an owner reports it, for the config it was made of."""
        self._watchers: tuple[Watcher, ...] = ()
        self.copy = FleetCopy(self._changed, self._patched, self.hub.event)
        self._asking: set[SlotRef] = set()
        self.cut_off = CutOff(self.hub.event)
        self._tasks: list[asyncio.Task[Any]] = []

    async def start(self) -> None:
        """Open the registry (importing printers.json into an empty one), follow every
        slot, publish to browsers."""
        self._connection = await connect(self._url, "kybercore-front")
        await self.kv.open(self._nc)
        if self._printers_file.exists():
            printers = await asyncio.to_thread(read_printers, self._printers_file)
            if imported := await self.kv.import_if_empty(printers):
                log.info("imported %d printers from %s", imported, self._printers_file)
        self._on_printers(await self.kv.printers())
        await self._nc.subscribe(patch_subject("*", "*"), cb=self._on_batch)
        await self._nc.subscribe("kc.gcode.*", cb=self._on_console_line)
        self.hub.start()
        self._tasks = [
            asyncio.create_task(self.kv.watch(self._on_printers), name="registry-watch"),
            asyncio.create_task(self._watch_slots(), name="front-slots"),
        ]

    async def stop(self) -> None:
        """Stop following and publishing."""
        for task in self._tasks:
            await cancel_and_wait(task)
        await self.hub.stop()
        if self._connection is not None:
            await self._connection.close()

    @property
    def _nc(self) -> Client:
        assert self._connection is not None, "start() first"
        return self._connection

    @property
    def nc(self) -> Client:
        """The front's NATS connection (once started)."""
        return self._nc

    @property
    def broker_connected(self) -> bool | None:
        """Whether this front is connected to the broker, as it last noticed (4 times a
        second; False before it started). Health, readiness, metrics, the stale tiles'
        message and the browsers' banner all read this one state (:mod:`.cut_off`)."""
        return self._connection is not None and self.cut_off.since is None

    def broker_frame(self) -> dict[str, Any] | None:
        """The ``broker`` event while this front is cut off (:mod:`.cut_off`)."""
        return self.cut_off.frame()

    # -- following -----------------------------------------------------------------------

    def _on_printers(self, printers: list[PrinterConfig]) -> None:
        before = set(self._configs)
        self._configs = {p.id: p for p in printers}
        self._unreported = {k: v for k, v in self._unreported.items() if k in self._configs}
        for printer_id in before | set(self._configs):
            self._changed(printer_id)

    def _slot(self, printer_id: str) -> SlotRef:
        config = self._configs.get(printer_id)
        return SlotRef(config.site if config else "", slot_of(printer_id, self._slots))

    async def _on_batch(self, msg: Msg) -> None:
        slot = slot_of_subject(msg.subject)
        if slot.slot < self._slots and self.copy.batch(slot, loads(msg.data), time.monotonic()):
            self._ask_snapshot(slot)

    async def _on_console_line(self, msg: Msg) -> None:
        line = loads(msg.data)
        self.hub.console(str(line["printer"]), str(line["message"]))

    async def _watch_slots(self) -> None:
        while True:
            await asyncio.sleep(CHECK_SECONDS)
            for slot in self.copy.check(time.monotonic()):
                self._ask_snapshot(slot)
            self.cut_off.follow(self._nc.is_connected)

    def _ask_snapshot(self, slot: SlotRef) -> None:
        if slot not in self._asking:
            self._asking.add(slot)
            task = asyncio.create_task(self._snapshot(slot))
            task.add_done_callback(lambda _t: self._asking.discard(slot))

    async def _snapshot(self, slot: SlotRef) -> None:
        subject = snap_subject(slot.slot, slot.site)
        try:
            reply = await self._nc.request(subject, b"", timeout=SNAPSHOT_TIMEOUT)
        except (NoRespondersError, NatsTimeout, TimeoutError):
            return  # the slot is moving; its next batch asks again
        body = loads(reply.data)
        if "views" in body and self.copy.snapshot(slot, body, time.monotonic()):
            self._asking.discard(slot)
            self._ask_snapshot(slot)

    def _patched(self, printer_id: str, view: View, patch: dict[str, Any]) -> None:
        # The worker's patch goes on to the browsers as it is (no render, no diff), unless
        # the front shows the printer otherwise: not in its registry yet, or stale.
        if printer_id in self._configs and not self.copy.is_stale(self._slot(printer_id)):
            self.hub.patched(printer_id, view, patch)
            self._tell(printer_id, patch)
        else:
            self._changed(printer_id)

    def _changed(self, printer_id: str) -> None:
        """The printer's view may have changed as a whole: render it again."""
        self.hub.mark(printer_id)
        self._tell(printer_id, None)

    def watch(self, watcher: Watcher) -> Callable[[], None]:
        """Tell ``watcher`` of every change to a view (see :data:`Watcher`), from the
        event loop, as it is applied; returns the way to stop. It runs for every patch:
        it must be quick, and must not raise (what it raises is logged)."""
        self._watchers = (*self._watchers, watcher)

        def unwatch() -> None:
            self._watchers = tuple(w for w in self._watchers if w is not watcher)

        return unwatch

    def _tell(self, printer_id: str, patch: dict[str, Any] | None) -> None:
        # A tuple replaced on (un)watch: a watcher may stop watching while being told.
        for watcher in self._watchers:
            try:
                watcher(printer_id, patch)
            except Exception:
                # One watcher's bug must not stop the views from following the workers.
                log.exception("front: a watcher of %s failed", printer_id)

    def _render(self, printer_id: str) -> View | None:
        config = self._configs.get(printer_id)
        if config is None:
            return None
        view = self.copy.views.get(printer_id)
        if view is None:  # no owner has reported it yet
            # Kept: the queue and the notifications read every printer each round, and at
            # 5,000 printers coming online, fusing each every time took a third of a core.
            made = self._unreported.get(printer_id)
            if made is None or made[0] is not config:
                unheard = LivePrinter(connection_error=_unheard(config.site))
                made = self._unreported[printer_id] = (config, fuse(config, unheard))
            return made[1]
        if self.copy.is_stale(slot := self._slot(printer_id)):
            message = silent_owner(slot.site) if self.broker_connected else STALE_MESSAGE
            return {**view, "connection": "stale", "connection_error": message}
        return view

    # -- reading -------------------------------------------------------------------------

    def configs(self) -> list[PrinterConfig]:
        """Every printer in the registry bucket, as the front last read it."""
        return list(self._configs.values())

    def current_view(self, printer_id: str) -> View:
        """One printer's view as the front knows it now (what the next publish sends):
        its owner's last view, marked stale when its slot's owner went silent, or one that
        says connecting when no owner has reported it yet."""
        view = self._render(printer_id)
        if view is None:
            raise UnknownPrinter(printer_id)
        return view

    def reported(self, printer_id: str) -> bool:
        """Whether a worker reports the printer now: its slot's owner was heard within
        :data:`~.follow.STALE_SECONDS` (never, for a slot nobody holds)."""
        return not self.copy.is_stale(self._slot(printer_id))

    def view(self, printer_id: str) -> View:
        """One printer's view, as last published."""
        view = self.hub.view(printer_id) or self._render(printer_id)
        if view is None:
            raise UnknownPrinter(printer_id)
        return view

    def config(self, printer_id: str) -> PrinterConfig:
        """A printer's configuration, from the registry bucket."""
        config = self._configs.get(printer_id)
        if config is None:
            raise UnknownPrinter(printer_id)
        return config

    def client(self, printer_id: str) -> MoonrakerClient:
        """Not on a front: its printers' sockets are held by workers."""
        self.config(printer_id)
        raise not_on_front("Reading the printer's Moonraker directly")

    # -- the registry --------------------------------------------------------------------

    async def add_printer(self, new: PrinterCreate, *, check: bool = False) -> View:
        """Add a printer to the registry bucket; a worker connects to it."""
        if check:
            key = new.api_key.get_secret_value() if new.api_key else None
            await self.probe(new.moonraker_url, key)
        created = await self.kv.add(new)
        self._on_printers([*self._configs.values(), created])
        self.hub.refresh(created.id)
        return self.view(created.id)

    async def update_printer(self, printer_id: str, patch: PrinterUpdate) -> View:
        """Edit a printer in the registry bucket (compare-and-set: a conflict is a 409)."""
        self.config(printer_id)
        updated = await self.kv.update(printer_id, patch)
        self._on_printers([updated if p.id == printer_id else p for p in self._configs.values()])
        self.hub.refresh(printer_id)
        return self.view(printer_id)

    async def remove_printer(self, printer_id: str) -> None:
        """Remove a printer from the registry bucket."""
        self.config(printer_id)
        await self.kv.remove(printer_id)
        self._on_printers([p for p in self._configs.values() if p.id != printer_id])
        self.hub.refresh(printer_id)

    # -- commands ------------------------------------------------------------------------

    async def command(self, printer_id: str, op: str, **args: Any) -> Any:
        """Run the command ``op`` (:mod:`.ops`) on the printer's owner, with the slot epoch
        the front knows; its result (see :func:`~kybercore.scale.commands.send_command`)."""
        self.config(printer_id)
        epoch = self.copy.epoch(self._slot(printer_id))
        return await send_command(self._nc, printer_id, op, args, epoch=epoch)

    async def dry_run(
        self,
        printer_id: str,
        action: str,
        params: Mapping[str, Any] | None = None,
        force: bool = False,
    ) -> Verdict:
        """What would happen, judged by the printer's owner against its live state."""
        params = dict(params or {})
        body = await self.command(printer_id, "dry_run", action=action, params=params, force=force)
        return decode_verdict(body)

    async def act(
        self,
        printer_id: str,
        action: str,
        params: Mapping[str, Any] | None = None,
        *,
        force: bool = False,
        confirm: bool = False,
    ) -> ActionOutcome:
        """Run ``action`` on the printer's owner: validated there, its real outcome here."""
        body = await self.command(
            printer_id, "act", action=action, params=dict(params or {}), force=force,
            confirm=confirm,
        )  # fmt: skip
        outcome = decode_outcome(body)
        if outcome.error is not None:
            raise outcome.error
        return outcome

    async def upload(
        self,
        printer_id: str,
        filename: str,
        content: bytes | BinaryIO,
        *,
        start: bool = False,
        confirm: bool = False,
    ) -> ActionOutcome:
        """Stream the file through the ``kc_uploads`` object store to the printer's owner,
        which uploads it (and starts it) as ``kybercore serve`` does; its real outcome."""
        self.config(printer_id)
        slot = self._slot(printer_id)
        body = await send_upload(
            self._nc, printer_id, filename, content, start=start, confirm=confirm,
            epoch=lambda: self.copy.epoch(slot),
        )  # fmt: skip
        outcome = decode_outcome(body)
        if outcome.error is not None:
            raise outcome.error
        return outcome

    async def files(self, printer_id: str) -> list[dict[str, Any]]:
        """The printer's G-code files, newest first (from its owner)."""
        found: list[dict[str, Any]] = await self.command(printer_id, "files")
        return found

    async def delete_file(self, printer_id: str, path: str) -> None:
        """Delete a G-code file (its owner refuses the one being printed)."""
        await self.command(printer_id, "delete_file", path=path)

    async def file_metadata(self, printer_id: str, filename: str) -> dict[str, Any]:
        """Moonraker's metadata of one file (from the printer's owner)."""
        found: dict[str, Any] = await self.command(printer_id, "file_metadata", filename=filename)
        return found

    async def console_history(self, printer_id: str, count: int) -> list[dict[str, Any]]:
        """The printer's last console entries (from its owner)."""
        found: list[dict[str, Any]] = await self.command(printer_id, "console_history", count=count)
        return found

    # -- reads -----------------------------------------------------------------------------

    async def macros(self, printer_id: str) -> list[Macro]:
        """The printer's G-code macros (its owner reads Klipper's configuration)."""
        return decode_macros(await self.command(printer_id, "macros"))

    async def exclude_object_status(self, printer_id: str) -> dict[str, Any] | None:
        """Klipper's ``exclude_object`` status (its owner reads it now)."""
        found: dict[str, Any] | None = await self.command(printer_id, "exclude_object")
        return found

    async def temperatures(self, printer_id: str, minutes: float) -> dict[str, Series]:
        """The printer's heaters over the last ``minutes`` (from its owner's ring)."""
        found: dict[str, Series] = await self.command(printer_id, "temperatures", minutes=minutes)
        return found

    async def thumbnail(self, printer_id: str, path: str) -> Image:
        """An image under the printer's ``gcodes/`` (through its owner)."""
        return decode_image(await self.command(printer_id, "thumbnail", path=path))

    async def cameras(self, printer_id: str) -> list[Webcam]:
        """The printer's enabled webcams (its owner's list)."""
        return decode_webcams(await self.command(printer_id, "cameras"))

    async def camera_snapshot(self, printer_id: str, name: str) -> Image:
        """One JPEG from the webcam ``name`` (through the printer's owner)."""
        return decode_image(await self.command(printer_id, "camera_snapshot", name=name))

    async def camera_stream(self, printer_id: str, name: str) -> CameraStream:
        """The webcam's live MJPEG stream, relayed by the printer's owner (:mod:`.streams`)."""
        self.config(printer_id)
        epoch = self.copy.epoch(self._slot(printer_id))
        return await open_stream(self._nc, printer_id, name, epoch=epoch)


def _unheard(site: str) -> str:
    # Said until a worker reports the printer: a site without workers would otherwise show
    # "connecting" with no reason forever.
    if site:
        return (
            f"No KyberCore worker of site '{site}' has reported this printer yet: start one "
            f"there with `kybercore ingest --site {site}`."
        )
    return "No KyberCore worker has reported this printer yet: is `kybercore ingest` running?"
