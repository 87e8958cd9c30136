"""The printers in a JetStream key-value bucket: the same rules as printers.json, and two
processes editing one printer at once cannot both win."""

from __future__ import annotations

import asyncio

import pytest

from kybercore.errors import ActionRejected, InvalidInput, UnknownPrinter
from kybercore.registry.models import PrinterConfig, PrinterCreate, PrinterUpdate
from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.registry import KvRegistry


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

        await registry.remove(added.id)
        with pytest.raises(UnknownPrinter):
            await registry.remove(added.id)
        async with asyncio.timeout(10):
            while not seen or seen[-1] != ["p-2"]:
                await asyncio.sleep(0.05)  # poll the watcher's callbacks, deadline above
        watcher.cancel()
    finally:
        await nc.close()
