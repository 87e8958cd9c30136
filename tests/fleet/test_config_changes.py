"""printers.json edits on disk and through the API, interleaved: the last write wins in
memory as it does on disk.

No Moonraker is involved (every printer points at an unused loopback port): this is about
which fleet the service applies, not about the printers.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from kybercore.fleet.service import FleetService
from kybercore.registry.models import PrinterConfig, PrinterCreate
from kybercore.registry.store import PrinterRegistry, write_printers
from kybercore.sim.stack import free_port


class SlowDiskRegistry(PrinterRegistry):
    """A registry whose watcher reload can be held after it has read the file: a disk (or a
    scheduler) slower than the API's write that lands meanwhile."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.hold = False
        self.read = threading.Event()
        self.go_on = threading.Event()

    def reload(self) -> list[PrinterConfig]:
        printers = super().reload()
        if self.hold:
            self.read.set()
            self.go_on.wait(10)
        return printers


@pytest.fixture
async def slow_fleet(
    tmp_path: Path, http: httpx.AsyncClient
) -> AsyncIterator[tuple[FleetService, SlowDiskRegistry]]:
    path = tmp_path / "printers.json"
    url = f"http://127.0.0.1:{free_port()}"
    write_printers(path, [PrinterConfig(id="a", name="A", moonraker_url=url)])
    registry = SlowDiskRegistry(path)
    service = FleetService(registry, http, watch_interval=0.02)
    await service.start()
    try:
        yield service, registry
    finally:
        registry.go_on.set()
        await service.stop()


async def test_a_watcher_reload_older_than_an_api_write_does_not_revert_it(
    slow_fleet: tuple[FleetService, SlowDiskRegistry],
) -> None:
    service, registry = slow_fleet
    browser = service.hub.connect()
    url = service.config("a").moonraker_url
    # Another process edits the file; the watcher reads it, then is held there.
    registry.hold = True
    write_printers(
        registry.path, [PrinterConfig(id="a", name="A", moonraker_url=url, notes="by hand")]
    )
    await asyncio.to_thread(registry.read.wait, 10)
    registry.hold = False
    # Meanwhile the API adds a printer: on disk and in the fleet.
    other = f"http://127.0.0.1:{free_port()}"  # a Moonraker of its own; it need not answer
    await service.add_printer(PrinterCreate(id="b", name="B", moonraker_url=other))
    assert [p.id for p in registry.printers] == ["a", "b"]
    # Now the watcher goes on with what it read before that write.
    registry.go_on.set()
    while b'"type":"config"' not in await asyncio.wait_for(browser.queue.get(), 10):
        pass
    assert [p.config.id for p in service.sessions.all()] == ["a", "b"]
    assert service.view("b")["id"] == "b"
    assert service.config("a").notes == "by hand"
