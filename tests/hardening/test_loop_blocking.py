"""Nothing that can block goes on the event loop: while another process holds printers.json's
lock (as ``kybercore printers edit`` does during its write), API edits wait in worker
threads, reads of the fleet answer at once, and asyncio debug mode's slow-callback log
(50 ms, with 5× slack) stays silent."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from kybercore.api.app import create_app
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry, read_printers, write_printers
from kybercore.sim.stack import free_port
from tests.helpers import loop_watchdog

READ_WITHIN = 2.0
"""Promise: a fleet read answers while a write waits for the lock. Idle: ~2 ms; 0.53 s was
seen for three reads on a machine busy with two other suites. A loop blocked on the lock
would wait until after the reads (the holder lets go only then), so any bound catches it."""

# Another process's write: take the lock, change the file, hold the lock until told.
HOLDER = """
import sys, filelock
from pathlib import Path
path = Path(sys.argv[1])
with filelock.FileLock(str(path) + ".lock"):
    path.write_text(path.read_text().replace('"notes": ""', '"notes": "by the CLI"', 1))
    print("HELD", flush=True)
    sys.stdin.readline()
"""


@pytest.fixture
async def api(tmp_path: Path) -> AsyncIterator[httpx.AsyncClient]:
    path = tmp_path / "printers.json"
    url = f"http://127.0.0.1:{free_port()}"  # nothing listens: no Moonraker involved
    write_printers(
        path,
        [PrinterConfig(id=p, name=p.upper(), moonraker_url=url) for p in ("a", "b", "c")],
    )
    app = create_app(PrinterRegistry(path), watch_interval=0.05)
    async with (
        app.router.lifespan_context(app),
        httpx.AsyncClient(
            transport=httpx.ASGITransport(app), base_url="http://127.0.0.1", timeout=30
        ) as client,
    ):
        yield client


async def test_api_edits_under_a_held_file_lock_never_block_the_loop(
    api: httpx.AsyncClient, tmp_path: Path
) -> None:
    path = tmp_path / "printers.json"
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert holder.stdin is not None
    assert holder.stdout is not None
    try:
        with loop_watchdog() as slow:
            assert await asyncio.to_thread(holder.stdout.readline) == "HELD\n"
            edits = [
                asyncio.ensure_future(api.patch(f"/api/printers/{p}", json={"location": "B2"}))
                for p in ("a", "b")
            ]
            for _ in range(10):  # reads go on while both edits wait for the lock
                started = time.perf_counter()
                assert (await api.get("/api/printers")).status_code == 200
                assert (await api.get("/api/printers/c")).status_code == 200
                assert (await api.get("/api/health")).status_code == 200
                assert time.perf_counter() - started < READ_WITHIN
                await asyncio.sleep(0.05)  # let the watcher poll between reads
            assert not any(edit.done() for edit in edits)
            holder.stdin.write("\n")
            holder.stdin.flush()
            answers = await asyncio.gather(*edits)
            assert [a.status_code for a in answers] == [200, 200], [a.text for a in answers]
        assert slow.lines == [], slow.lines
    finally:
        holder.kill()
        holder.wait()
    stored = {p.id: (p.location, p.notes) for p in read_printers(path)}
    assert stored == {"a": ("B2", "by the CLI"), "b": ("B2", ""), "c": ("", "")}
