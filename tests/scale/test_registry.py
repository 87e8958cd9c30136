"""The printers in a JetStream key-value bucket: the same rules as printers.json, and two
processes editing one printer at once cannot both win."""

from __future__ import annotations

import asyncio
import contextlib

import pytest
from nats.js.errors import KeyNotFoundError
from nats.js.kv import KeyValue
from pydantic import SecretStr

from kybercore.errors import ActionRejected, BrokerUnavailable, InvalidInput, UnknownPrinter
from kybercore.registry.models import PrinterConfig, PrinterCreate, PrinterUpdate
from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.buckets import bucket_keys
from kybercore.scale.registry import STORED, KvRegistry, fleet_order
from tests.helpers import wait_for
from tests.scale.at_once import at_once


def test_the_fleet_is_in_natural_order_whatever_order_the_bucket_gives() -> None:
    ids = ["printer-10", "farm-b-2", "printer-2", "printer-1", "farm-b-10", "x", "printer-02a"]
    printers = [PrinterConfig(id=i, name=i, moonraker_url="http://127.0.0.1:1") for i in ids]
    expected = ["farm-b-2", "farm-b-10", "printer-1", "printer-2", "printer-02a", "printer-10", "x"]
    assert [p.id for p in fleet_order(printers)] == expected
    # Again, from the keys it remembers: the same order.
    assert [p.id for p in fleet_order(printers[::-1])] == expected


async def test_add_edit_remove_and_a_conflicting_edit(nats_server: LocalServer) -> None:
    nc = await connect(nats_server.url, "test")
    try:
        registry, other = KvRegistry(), KvRegistry()
        await registry.open(nc)
        await other.open(nc)
        seen: list[list[str]] = []
        watcher = asyncio.create_task(registry.watch(lambda ps: seen.append([p.id for p in ps])))
        first = PrinterConfig(id="p-2", name="Two", moonraker_url="http://127.0.0.1:7126")
        assert await registry.import_if_empty([first]) == 1
        assert await registry.import_if_empty([first]) == 0  # only into an empty bucket
        added = await registry.add(PrinterCreate(name="P 10", moonraker_url="http://10.0.0.9"))
        assert [p.id for p in await other.printers()] == ["p-2", added.id]
        with pytest.raises(InvalidInput, match="already uses"):  # the printers.json rules
            await registry.add(PrinterCreate(name="Dup", moonraker_url="http://127.0.0.1:7126"))

        stale = await other._entries()  # another front read it before this edit
        await registry.update("p-2", PrinterUpdate(name="Renamed"))

        async def read_stale() -> dict[str, tuple[PrinterConfig, int]]:
            return stale

        other._entries = read_stale  # type: ignore[method-assign]
        with pytest.raises(ActionRejected) as conflict:
            await other.update("p-2", PrinterUpdate(name="Lost edit"))
        assert conflict.value.code == "conflict"
        assert (await registry.printers())[0].name == "Renamed"

        # A removal reads only its printer's key: one read before an edit loses too.
        stale_entry = await other.kv.get("p.p-2")
        await registry.update("p-2", PrinterUpdate(name="Renamed again"))

        async def get_stale(key: str) -> KeyValue.Entry:
            return stale_entry

        other.kv.get = get_stale  # type: ignore[method-assign,assignment]
        with pytest.raises(ActionRejected) as conflict:
            await other.remove("p-2")
        assert conflict.value.code == "conflict"
        assert (await registry.printers())[0].name == "Renamed again"

        await registry.remove(added.id)
        with pytest.raises(UnknownPrinter):
            await registry.remove(added.id)
        async with asyncio.timeout(10):
            while not seen or seen[-1] != ["p-2"]:
                await asyncio.sleep(0.05)  # poll the watcher's callbacks, deadline above
        watcher.cancel()
    finally:
        await nc.close()


async def test_an_import_is_told_in_a_few_calls_not_one_per_printer(
    nats_server: LocalServer,
) -> None:
    # Each call re-applies the whole fleet in a worker: one per entry of a big import
    # blocked its event loop for minutes (leases expired, sockets churned).
    nc = await connect(nats_server.url, "test")
    try:
        registry = KvRegistry()
        await registry.open(nc)
        seen: list[int] = []
        watcher = asyncio.create_task(registry.watch(lambda ps: seen.append(len(ps))))
        await wait_for(lambda: bool(seen), 10, "the initial (empty) list")
        printers = [
            PrinterConfig(
                id=f"p{i}", name=f"P {i}", moonraker_url=f"http://10.0.{i // 250}.{i % 250}"
            )
            for i in range(300)
        ]
        assert await registry.import_if_empty(printers) == 300
        await wait_for(lambda: seen[-1] == 300, 30, "all 300 printers told")
        watcher.cancel()
        # Created one by one, ~1 ms apart: a handful of calls (a busy machine may add some).
        assert len(seen) - 1 <= 30, seen
    finally:
        await nc.close()


class _EarlyEndWatcher:
    """A fault injector around nats-py's real watcher: it says "no more initial values"
    (``None``) before delivering any, which nats-py's watch does on a busy event loop and
    which cannot be made to happen on demand."""

    def __init__(self, real: KeyValue.KeyWatcher) -> None:
        self._real = real
        self._ended = False

    async def updates(self, timeout: float) -> KeyValue.Entry | None:
        if not self._ended:
            self._ended = True
            return None
        return await self._real.updates(timeout=timeout)  # type: ignore[no-untyped-call, no-any-return]

    async def stop(self) -> None:
        await self._real.stop()  # type: ignore[no-untyped-call]


async def test_the_first_list_has_every_printer_even_when_the_watch_ends_its_own_too_soon(
    nats_server: LocalServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    nc = await connect(nats_server.url, "test")
    try:
        registry = KvRegistry()
        await registry.open(nc)
        ids = [f"p{i}" for i in range(5)]
        await registry.import_if_empty(
            [
                PrinterConfig(id=i, name=i, moonraker_url=f"http://127.0.0.1:71{n}")
                for n, i in enumerate(ids)
            ]
        )
        await registry.kv.put("p.broken", b"{half-written")
        real_watchall = registry.kv.watchall

        async def watchall_ending_early() -> _EarlyEndWatcher:
            return _EarlyEndWatcher(await real_watchall())

        monkeypatch.setattr(registry.kv, "watchall", watchall_ending_early)
        seen: list[list[str]] = []
        watcher = asyncio.create_task(registry.watch(lambda ps: seen.append([p.id for p in ps])))
        await wait_for(lambda: bool(seen), 10, "the first list")
        assert seen[0] == ids  # every printer, the broken entry skipped
        assert [p.id for p in await registry.printers()] == ids

        await registry.remove("p1")
        await wait_for(lambda: len(seen) > 1, 10, "the removal told")
        watcher.cancel()
        # The watch's own copies of what the first list had told nothing twice.
        assert seen[1:] == [["p0", "p2", "p3", "p4"]]
    finally:
        await nc.close()


class _DroppingWatcher(_EarlyEndWatcher):
    """A fault injector: the watch never delivers one key the bucket lists (what a key
    purged from the stream meanwhile does)."""

    def __init__(self, real: KeyValue.KeyWatcher, dropped: str) -> None:
        super().__init__(real)
        self._dropped = dropped

    async def updates(self, timeout: float) -> KeyValue.Entry | None:
        entry = await super().updates(timeout)
        while entry is not None and entry.key == self._dropped:
            entry = await super().updates(timeout)
        return entry


async def test_a_read_missing_a_listed_key_ends_with_the_rest(
    nats_server: LocalServer, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    nc = await connect(nats_server.url, "test")
    try:
        registry = KvRegistry()
        await registry.open(nc)
        await registry.import_if_empty(
            [PrinterConfig(id=i, name=i, moonraker_url=f"http://127.0.0.1:7{n}") for n, i in
             enumerate(("a", "b", "c"))]
        )  # fmt: skip
        real_watchall = registry.kv.watchall

        async def watchall_dropping() -> _DroppingWatcher:
            return _DroppingWatcher(await real_watchall(), "p.b")

        monkeypatch.setattr(registry.kv, "watchall", watchall_dropping)
        monkeypatch.setattr("kybercore.scale.registry.READ_WAIT_SECONDS", 0.5)
        assert [p.id for p in await registry.printers()] == ["a", "c"]
        assert "registry: read without 1 listed key(s): p.b" in caplog.text
    finally:
        await nc.close()


async def test_api_keys_live_apart_and_only_workers_read_them(nats_server: LocalServer) -> None:
    nc = await connect(nats_server.url, "test")
    try:
        front, worker = KvRegistry(), KvRegistry(read_keys=True)
        await front.open(nc)
        await worker.open(nc)
        new = PrinterCreate(name="Keyed", moonraker_url="http://10.0.0.7", api_key="s3cret-key")
        added = await front.add(new)
        entry = await front.kv.get(f"p.{added.id}")
        assert entry.value is not None
        assert b"s3cret" not in entry.value  # the registry bucket never holds the key
        assert (await front.secrets.get(f"p.{added.id}")).value == b"s3cret-key"
        assert (await front.printers())[0].api_key == STORED
        assert (await worker.printers())[0].api_key == SecretStr("s3cret-key")
        # An edit that does not touch the key keeps it; a move to another server needs it.
        await front.update(added.id, PrinterUpdate(name="Renamed"))
        assert (await worker.printers())[0].api_key == SecretStr("s3cret-key")
        with pytest.raises(InvalidInput, match="API key again"):
            await front.update(added.id, PrinterUpdate(moonraker_url="http://10.0.0.8"))
        await front.remove(added.id)
        with pytest.raises(KeyNotFoundError):
            await front.secrets.get(f"p.{added.id}")
    finally:
        await nc.close()


async def test_bucket_keys_lists_every_key_under_a_prefix_deleted_ones_too(
    nats_server: LocalServer,
) -> None:
    # What the registry and the leases read instead of nats-py's KeyValue.keys(), which a
    # busy loop made end early (a front found no printer to edit, in CI).
    nc = await connect(nats_server.url, "test")
    try:
        js = nc.jetstream()
        kv = await js.create_key_value(bucket="kc_test", history=1)
        assert await bucket_keys(js, "kc_test") == []
        for key in ("p.a", "p.b", "p.c", "other.a"):
            await kv.put(key, b"1")
        await kv.delete("p.b")
        assert sorted(await bucket_keys(js, "kc_test", "p.")) == ["p.a", "p.b", "p.c"]
        assert sorted(await bucket_keys(js, "kc_test")) == ["other.a", "p.a", "p.b", "p.c"]
        with pytest.raises(KeyNotFoundError):  # the deleted one says so when read
            await kv.get("p.b")
    finally:
        await nc.close()


async def test_a_broker_that_stops_answering_is_one_clear_error(nats_server: LocalServer) -> None:
    nc = await connect(nats_server.url, "test")
    try:
        registry = KvRegistry()
        await registry.open(nc)
        await registry.import_if_empty(
            [PrinterConfig(id="a", name="a", moonraker_url="http://127.0.0.1:7101")]
        )
        real_delete = registry.kv.delete

        async def delete_once_the_broker_stopped(key: str, last: int | None = None) -> bool:
            # The broker gone between the removal's read and its write: no one can tell
            # whether the write got there.
            await asyncio.to_thread(nats_server.stop)
            return await real_delete(key, last=last)

        registry.kv.delete = delete_once_the_broker_stopped  # type: ignore[method-assign]
        with pytest.raises(BrokerUnavailable) as during:
            await registry.remove("a")
        assert "while removing printer 'a': it may or may not have been made" in str(during.value)
        assert "reload the printer list" in during.value.message

        await wait_for(lambda: not nc.is_connected, 10, "the connection to notice")
        with (
            at_once("edit refused"),
            pytest.raises(BrokerUnavailable, match="not read and nothing was changed"),
        ):
            await registry.update("a", PrinterUpdate(name="b"))
    finally:
        with contextlib.suppress(Exception):  # the connection is still trying to get back
            await nc.close()
