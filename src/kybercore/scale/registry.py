"""The fleet's printers in a JetStream key-value bucket, when KyberCore runs on NATS.

One key per printer (``p.<id>``, the printer's configuration as printers.json stores it).
The same rules as printers.json (:mod:`kybercore.registry.changes`) decide what a change
may do; the bucket makes it safe between processes: an add is a ``create`` (refused if the
id appeared meanwhile), an edit and a delete are compare-and-set on the key's revision, so
two fronts editing one printer at once cannot both win: the second gets a conflict (409).

Workers and fronts :meth:`KvRegistry.watch` the bucket: the whole list at start, then every
change. ``printers.json`` is the import and export format (``kybercore front
--printers-file``).

Moonraker API keys are not in ``kc_registry`` but in ``kc_secrets`` (same key names): the
registry entry only says whether one is set. Workers read the keys (they call Moonraker);
fronts write them and never need to read them, so a deployment can deny fronts' accounts
the reads of that bucket (``$JS.API.DIRECT.GET.KV_kc_secrets.>``). In a front's copy a set
key is the placeholder :data:`STORED`.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import re
from collections.abc import Callable, Iterator
from typing import Final

import nats.errors
from nats.aio.client import Client
from nats.js import JetStreamContext
from nats.js.errors import (
    BadRequestError,
    KeyNotFoundError,
    KeyWrongLastSequenceError,
    NoStreamResponseError,
    ServiceUnavailableError,
)
from nats.js.kv import KeyValue
from pydantic import SecretStr

from kybercore.errors import ActionRejected, BrokerUnavailable
from kybercore.registry import changes
from kybercore.registry.models import PrinterConfig, PrinterCreate, PrinterUpdate
from kybercore.scale.broker import require_connected
from kybercore.scale.buckets import bucket_keys, key_value, wrong_revision
from kybercore.scale.wire import dumps, loads

log = logging.getLogger(__name__)

BUCKET: Final = "kc_registry"
SECRETS: Final = "kc_secrets"
PREFIX: Final = "p."
STORED: Final = SecretStr("stored-in-kc_secrets")
"""A front's stand-in for an API key it does not read."""
BATCH_SECONDS: Final = 0.05
"""A change is told once no other has come for this long..."""
BATCH_MAX_SECONDS: Final = 1.0
"""...or this long after it came, however many follow (a long import shows as it goes)."""
READ_WAIT_SECONDS: Final = 10.0
"""Reading the bucket waits this long at most for the next key it listed."""
_NOT_READ: Final = "the printer registry was not read and nothing was changed"
_QUIET: Final = object()
_NO_ANSWER: Final = (
    nats.errors.TimeoutError,
    nats.errors.NoRespondersError,
    nats.errors.ConnectionClosedError,
    NoStreamResponseError,  # a cluster electing the bucket's leader
    ServiceUnavailableError,
)

OnPrinters = Callable[[list[PrinterConfig]], None]


def _key(printer_id: str) -> str:
    return PREFIX + printer_id


def fleet_order(printers: list[PrinterConfig]) -> list[PrinterConfig]:
    """Printers in a stable, human order (printer-2 before printer-10)."""
    return sorted(printers, key=lambda p: _natural(p.id))


# Remembered: every batch of registry changes sorts the whole fleet again, and at 5,000
# printers making the keys was most of a worker's time while an import trickled in.
@functools.lru_cache(maxsize=1 << 16)
def _natural(text: str) -> tuple[tuple[int, str], ...]:
    # (0, digits as a number) sorts numbers among themselves; (1, text) after them.
    return tuple((0, f"{int(t):020d}") if t.isdigit() else (1, t) for t in re.split(r"(\d+)", text))


def _conflict(printer_id: str) -> ActionRejected:
    return ActionRejected(
        f"Printer '{printer_id}' was changed by someone else at the same time. Reload it and "
        "make your change again.",
        code="conflict",
    )


@contextlib.contextmanager
def _broker_answers(change: str | None = None) -> Iterator[None]:
    """The broker's silence as :class:`BrokerUnavailable`, said once to whoever asked (a
    front's API, the CLI) instead of nats-py's bare timeout. ``change``: the write under
    way, whose outcome is then unknown; None for a read."""
    try:
        yield
    except _NO_ANSWER:
        if change is None:
            message = (
                "Could not read the printer registry: the NATS broker did not answer. "
                "Check that nats-server is running and reachable, then try again."
            )
        else:
            message = (
                f"The NATS broker did not answer while {change}: it may or may not have been "
                "made. Check that nats-server is running, reload the printer list, and make "
                "the change again if it is not there."
            )
        raise BrokerUnavailable(message) from None


class KvRegistry:
    """The fleet's printers in the ``kc_registry`` bucket."""

    def __init__(self, *, read_keys: bool = False) -> None:
        """``read_keys``: fill in the API keys (workers); else :data:`STORED` (fronts)."""
        self._nc: Client | None = None
        self._js: JetStreamContext | None = None
        self._kv: KeyValue | None = None
        self._secrets: KeyValue | None = None
        self._read_keys = read_keys

    async def open(self, nc: Client) -> None:
        """Open (or create) the buckets; file storage, so they outlive a broker restart."""
        self._nc = nc
        self._js = js = nc.jetstream()
        self._kv = await key_value(js, BUCKET, history=10)
        self._secrets = await key_value(js, SECRETS, history=1)

    @property
    def kv(self) -> KeyValue:
        """The registry bucket (after :meth:`open`)."""
        assert self._kv is not None, "open() first"
        return self._kv

    @property
    def secrets(self) -> KeyValue:
        """The API keys' bucket (after :meth:`open`)."""
        assert self._secrets is not None, "open() first"
        return self._secrets

    async def _decode(self, value: bytes) -> PrinterConfig:
        data = loads(value)
        key_set = bool(data.pop("api_key_set", False))
        config = PrinterConfig.model_validate(data)
        if not key_set:
            return config
        key = STORED
        if self._read_keys:
            try:
                stored = (await self.secrets.get(_key(config.id))).value
                key = SecretStr(stored.decode()) if stored else STORED
            except KeyNotFoundError:
                log.warning("registry: %s has an API key set but none stored", config.id)
        return config.model_copy(update={"api_key": key})

    async def _store_key(self, config: PrinterConfig, changed: bool = True) -> bytes:
        """Write the key (when it ``changed``) to kc_secrets; the registry entry's bytes."""
        if changed and config.api_key is not None and config.api_key != STORED:
            await self.secrets.put(_key(config.id), config.api_key.get_secret_value().encode())
        elif changed and config.api_key is None:
            with contextlib.suppress(KeyNotFoundError):
                await self.secrets.delete(_key(config.id))
        data = config.to_file_dict()
        data["api_key_set"] = data.pop("api_key") is not None
        return dumps(data)

    async def _entries(self) -> dict[str, tuple[PrinterConfig, int]]:
        """Every printer with its key's revision; a broken entry is skipped, logged."""
        with _broker_answers():
            watcher = await self.kv.watchall()
            try:
                return await self._read(watcher)
            finally:
                await _stop(watcher)

    async def _read(self, watcher: KeyValue.KeyWatcher) -> dict[str, tuple[PrinterConfig, int]]:
        """Every printer, from a watch of the bucket just started (the last value of each
        key, then every change), with its key's revision.

        nats-py's watch marks the end of its first values (``None``) too soon on a busy
        event loop: before it has delivered them. So the end is known from the bucket's
        own list of keys instead, read after the watch began: once the watch has delivered
        each of them, the read is whole (a later change comes after it, as a change). One
        watch, not one read per key: 0.4 s for 5,000 printers instead of 2.6 s."""
        assert self._js is not None, "open() first"
        missing = set(await bucket_keys(self._js, BUCKET, PREFIX))
        found: dict[str, tuple[PrinterConfig, int]] = {}
        while missing:
            try:
                entry = await watcher.updates(timeout=READ_WAIT_SECONDS)  # type: ignore[no-untyped-call]
            except TimeoutError:
                # Only a key removed from the stream meanwhile (a purge) is never delivered.
                named = ", ".join(sorted(missing)[:5])
                log.warning("registry: read without %d listed key(s): %s", len(missing), named)
                break
            if entry is not None:
                missing.discard(entry.key)
                await self._apply(found, entry)
        return found

    async def _apply(
        self, found: dict[str, tuple[PrinterConfig, int]], entry: KeyValue.Entry
    ) -> bool:
        """Apply one entry of a watch to ``found``; whether it changed anything. A key that
        is not a printer's, or a broken entry, is skipped (the latter logged)."""
        if not entry.key.startswith(PREFIX):
            return False
        printer_id = entry.key[len(PREFIX) :]
        if entry.operation in ("DEL", "PURGE") or not entry.value:
            return found.pop(printer_id, None) is not None
        try:
            config = await self._decode(entry.value)
        except ValueError as exc:
            log.warning("registry: printer %s skipped: %s", printer_id, exc)
            return False
        found[printer_id] = (config, entry.revision or 0)
        return True

    async def printers(self) -> list[PrinterConfig]:
        """Every printer, in fleet order."""
        require_connected(self._nc, _NOT_READ)
        return _configs(await self._entries())

    async def add(self, new: PrinterCreate) -> PrinterConfig:
        """Add a printer (the rules of printers.json); a clash with a concurrent add is a
        conflict."""
        printers = await self.printers()  # checks the connection
        printer = changes.add_printer(printers, new)
        try:
            with _broker_answers(f"adding printer '{printer.id}'"):
                await self.kv.create(_key(printer.id), await self._store_key(printer))
        except KeyWrongLastSequenceError:
            raise _conflict(printer.id) from None
        return printer

    async def update(self, printer_id: str, patch: PrinterUpdate) -> PrinterConfig:
        """Edit a printer: compare-and-set on the revision it was read at."""
        require_connected(self._nc, _NOT_READ)
        entries = await self._entries()
        printers = _configs(entries)
        updated = changes.update_printer(printers, printer_id, patch)
        try:
            with _broker_answers(f"editing printer '{printer_id}'"):
                value = await self._store_key(updated, changed="api_key" in patch.model_fields_set)
                await self.kv.update(_key(printer_id), value, last=entries[printer_id][1])
        except KeyWrongLastSequenceError:
            raise _conflict(printer_id) from None
        return updated

    async def remove(self, printer_id: str) -> PrinterConfig:
        """Remove a printer: compare-and-set on the revision it was read at. Only its own
        key is read: no rule about the others applies (an edit's does)."""
        require_connected(self._nc, _NOT_READ)
        found: dict[str, tuple[PrinterConfig, int]] = {}
        with _broker_answers(), contextlib.suppress(KeyNotFoundError):
            await self._apply(found, await self.kv.get(_key(printer_id)))
        removed = changes.remove_printer(_configs(found), printer_id)
        with _broker_answers(f"removing printer '{printer_id}'"):
            try:
                await self.kv.delete(_key(printer_id), last=found[printer_id][1])
            except BadRequestError as exc:
                if wrong_revision(exc):
                    raise _conflict(printer_id) from None
                raise
            with contextlib.suppress(KeyNotFoundError):
                await self.secrets.delete(_key(printer_id))
        return removed

    async def import_if_empty(self, printers: list[PrinterConfig]) -> int:
        """Load ``printers`` (from printers.json) into an empty bucket; how many were."""
        if await self._entries():
            return 0
        for printer in printers:
            with (
                _broker_answers(f"importing printer '{printer.id}'"),
                contextlib.suppress(KeyWrongLastSequenceError),  # another front won
            ):
                await self.kv.create(_key(printer.id), await self._store_key(printer))
        return len(printers)

    async def watch(self, on_change: OnPrinters) -> None:
        """Call ``on_change(printers)`` with the whole list now and after every change,
        forever (run it as a task; cancel it to stop). A broken entry is skipped, logged.

        Changes that come together (an import, a bulk edit) make one call: every call
        re-applies the whole fleet, so one per entry of a 2,000-printer import blocked a
        worker's event loop for minutes and its leases expired."""
        watcher = await self.kv.watchall()
        try:
            current = await self._read(watcher)
            on_change(_configs(current))
            due: float | None = None  # when the changes held since the last call must be told
            loop = asyncio.get_running_loop()
            while True:
                wait = 3600.0 if due is None else min(BATCH_SECONDS, max(due - loop.time(), 0))
                try:
                    entry = await watcher.updates(timeout=wait)  # type: ignore[no-untyped-call]
                except TimeoutError:
                    entry = _QUIET
                if due is not None and (entry is _QUIET or loop.time() >= due):
                    due = None
                    on_change(_configs(current))
                if entry is _QUIET or entry is None:
                    continue
                if await self._apply(current, entry) and due is None:
                    due = loop.time() + BATCH_MAX_SECONDS
        finally:
            await _stop(watcher)


def _configs(entries: dict[str, tuple[PrinterConfig, int]]) -> list[PrinterConfig]:
    return fleet_order([config for config, _ in entries.values()])


async def _stop(watcher: KeyValue.KeyWatcher) -> None:
    with contextlib.suppress(Exception):
        await watcher.stop()  # type: ignore[no-untyped-call]
    await asyncio.sleep(0)
