"""printers.json tells the truth about a write, and reading the fleet never waits for one.

- A write whose folder fsync fails after ``os.replace`` did change the file: the registry
  says so (the new fleet is in memory, a warning names the risk), never "not changed".
- :attr:`PrinterRegistry.printers` is read on the event loop: it must not wait for a writer
  that holds the registry's locks through fsyncs and up to 10 s of cross-process lock wait.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
from pathlib import Path

import filelock
import pytest

from kybercore import files
from kybercore.registry.models import PrinterCreate, PrinterUpdate
from kybercore.registry.store import PrinterRegistry, read_printers
from tests.helpers import WATCHDOG, loop_watchdog

_hosts = itertools.count(1)


def new(name: str) -> PrinterCreate:
    # Port 9 (discard): nothing listens; a host of its own, as one Moonraker drives one printer.
    return PrinterCreate(name=name, moonraker_url=f"http://127.0.0.{next(_hosts)}:9")


def test_a_failed_folder_fsync_after_the_replace_says_the_file_changed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "printers.json"
    registry = PrinterRegistry(path)
    registry.add(new("A"))

    def failing_dir_fsync(_folder: Path) -> None:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(files, "_fsync_dir", failing_dir_fsync)
    with caplog.at_level(logging.WARNING, logger="kybercore.files"):
        added = registry.add(new("B"))
    # The replace happened: the file, the registry and the answer all hold B.
    assert added.id == "b"
    assert [p.id for p in read_printers(path)] == ["a", "b"]
    assert [p.id for p in registry.printers] == ["a", "b"]
    warning = " ".join(r.getMessage() for r in caplog.records)
    assert "Input/output error" in warning
    assert "written" in warning
    assert "not changed" not in warning
    # And the write is ours: the watcher does not report it as an edit made on disk.
    assert not registry.changed()


async def test_reading_the_fleet_on_the_loop_never_waits_for_a_writer(tmp_path: Path) -> None:
    path = tmp_path / "printers.json"
    registry = PrinterRegistry(path)
    registry.add(new("A"))
    other_process = filelock.FileLock(str(path) + ".lock")  # another process's write, held
    other_process.acquire()
    with loop_watchdog() as slow:
        try:
            write = asyncio.ensure_future(
                asyncio.to_thread(registry.update, "a", PrinterUpdate(notes="edited"))
            )
            # The writer holds the registry's own lock while it waits for the file lock.
            while not registry._lock.locked():
                await asyncio.sleep(0.005)  # poll: the worker takes the lock at once
            for _ in range(5):
                started = time.perf_counter()
                assert [p.id for p in registry.printers] == ["a"]
                assert registry.get("a").notes == ""
                assert time.perf_counter() - started < WATCHDOG
                await asyncio.sleep(0.05)  # let the writer keep waiting between reads
            assert not write.done()
        finally:
            other_process.release()
        await asyncio.wait_for(write, 10)
    assert registry.get("a").notes == "edited"
    assert slow.lines == [], slow.lines
