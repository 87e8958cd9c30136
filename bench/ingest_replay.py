"""KyberCore's ingest path in one process, no sockets: CPU per 1,000 status updates.

``python -m bench.ingest_replay --printers N --clients M`` replays the load generator's
``notify_status_update`` frames (:class:`bench.printer_model.SimPrinter`, ~250 bytes) into
KyberCore's own objects, exactly as picows hands them over: ``MoonrakerLink._deliver``
(orjson) -> ``MoonrakerSession._dispatch`` -> ``Sessions._on_event`` (live state, heater
history, listeners) -> ``Hub`` ticks (render, diff, one encoded delta frame queued for each
of M browser clients, which are drained). Four updates per printer per second of
simulated time and ten hub ticks, as in ``kybercore serve``; the listeners are the
dispatcher's heating check behind its interest (the other services' interests pass no
progress-only update), so the figure needs no database.

What it leaves out, by design: the kernel, uvloop and picows (the end-to-end
:mod:`bench.ingest_cost` has them, and their floor). What it gains: CPU time that does not
move with the machine's load as wall-clock windows of N sockets do. With ``--compare-src``
the same replay runs on another ``src/`` in a child process, alternately, ``--rounds``
times; each tree's best round is reported, with ``orjson.loads`` of the same frames as the
floor and the share of the CPU its garbage collector took (the heap frozen first, with the
tree's own ``freeze_heap``, as ``kybercore serve`` does once the fleet is connected).
Prints one JSON line per tree, then a summary line.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import importlib
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import orjson

from bench.printer_model import FILENAME, UPDATES_PER_SECOND, SimPrinter

TICKS_PER_SECOND = 10
FRAMES_PER_PRINTER = 40  # 10 s of simulated time


def _frames(printers: int) -> list[list[bytes]]:
    """Each printer's next status frames, encoded as the load generator sends them."""
    out = []
    for index in range(printers):
        sim = SimPrinter(index)
        out.append(
            [
                orjson.dumps(
                    {
                        "jsonrpc": "2.0",
                        "method": "notify_status_update",
                        "params": [sim.step(), 1_000.0 + step / UPDATES_PER_SECOND],
                    }
                )
                for step in range(FRAMES_PER_PRINTER)
            ]
        )
    return out


async def replay(printers: int, clients: int) -> dict[str, float]:
    """Build N printers' ingest path, replay their frames; CPU s per 1,000 updates."""
    # kybercore ships no py.typed marker; mypy sees it as an untyped installed package.
    from kybercore.fleet.hub import Hub  # type: ignore[import-untyped, unused-ignore]
    from kybercore.fleet.sessions import FleetPrinter, Sessions  # type: ignore[import-untyped, unused-ignore]
    from kybercore.jobs.heating import is_heating  # type: ignore[import-untyped, unused-ignore]
    from kybercore.moonraker.link import MoonrakerLink  # type: ignore[import-untyped, unused-ignore]
    from kybercore.moonraker.session import MoonrakerSession  # type: ignore[import-untyped, unused-ignore]
    from kybercore.registry.models import PrinterConfig  # type: ignore[import-untyped, unused-ignore]

    frames = _frames(printers)
    async with httpx.AsyncClient() as http:
        sessions: Any = None
        hub = Hub(lambda pid: sessions.render(pid))
        sessions = Sessions(http, None, hub)  # type: ignore[arg-type, unused-ignore]
        listen: Any = sessions.listen
        # The tree's dispatcher listener, as it registers (with its interest if any): the
        # queue's printers hold it since the queue ran on fronts too, the dispatcher before.
        interest: Any = ()
        for module in ("kybercore.jobs.printers", "kybercore.jobs.dispatcher"):
            with contextlib.suppress(ImportError, AttributeError):
                interest = (importlib.import_module(module)._INTEREST,)
                break
        listen(lambda pid, _: is_heating(sessions.get(pid).live.status), *interest)
        links = []
        for index in range(printers):
            pid = f"p{index:05d}"
            config = PrinterConfig(id=pid, name=pid, moonraker_url="http://127.0.0.1:1")
            printer = FleetPrinter(config, None)
            sim = SimPrinter(index)
            live = printer.live
            live.connection, live.klippy_state, live.limits = "online", "ready", "known"
            live.status, live.file_meta = sim.status(), sim.metadata(FILENAME)
            live.updated_at = time.time()
            sessions._printers[pid] = printer
            session = MoonrakerSession(
                "ws://127.0.0.1:1/websocket",
                name=pid,
                api_key=None,
                subscription={},
                on_event=sessions._events_of(printer),
                client_name="replay",
                version="0",
            )
            links.append(MoonrakerLink(pid, session._dispatch, 5.0, 1 << 20))
        hub.flush()  # first views
        browsers = [hub.connect() for _ in range(clients)]
        # As serve does once the fleet is connected (with the tree's own collector settings).
        from kybercore.cli.serve import freeze_heap  # type: ignore[import-untyped, unused-ignore]

        freeze_heap()
        collecting: list[float] = []
        gc.callbacks.append(lambda phase, _: collecting.append(time.process_time()))
        per_tick = printers * UPDATES_PER_SECOND // TICKS_PER_SECOND
        ticks = printers * FRAMES_PER_PRINTER // per_tick
        started = time.process_time()
        cursor = 0
        for _ in range(ticks):
            for _ in range(per_tick):
                index, step = cursor % printers, cursor // printers
                links[index]._deliver(memoryview(frames[index][step]))
                cursor += 1
            hub.flush()
            for browser in browsers:  # the browsers read every frame
                while not browser.queue.empty():
                    browser.queue.get_nowait()
        cpu = time.process_time() - started
        gc.callbacks.clear()
    parse_started = time.process_time()
    for stream in frames:
        for frame in stream:
            orjson.loads(frame)
    parse = time.process_time() - parse_started
    in_gc = sum(collecting[1::2]) - sum(collecting[::2])  # (start, stop) pairs
    return {
        "events": cursor,
        "cpu_per_1000": cpu / cursor * 1000,
        "gc_share": round(in_gc / cpu, 3),
        "parse_floor_per_1000": parse / cursor * 1000,
    }


def _child(src: Path, printers: int, clients: int) -> dict[str, Any]:
    """One replay on the tree under ``src``, in a process of its own."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(src), str(Path.cwd())])}
    args = [sys.executable, "-m", "bench.ingest_replay", "--printers", str(printers)]
    args += ["--clients", str(clients), "--one"]
    done = subprocess.run(args, env=env, capture_output=True, check=True, timeout=900)
    result: dict[str, Any] = orjson.loads(done.stdout.splitlines()[-1])
    return result


def main() -> None:
    """``python -m bench.ingest_replay --printers N --clients M [--compare-src DIR]``."""
    parser = argparse.ArgumentParser(description="KyberCore ingest path, replayed")
    parser.add_argument("--printers", type=int, default=1_000)
    parser.add_argument("--clients", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--kybercore-src", type=Path, default=Path("src"))
    parser.add_argument("--compare-src", type=Path, action="append", default=[])
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        result = asyncio.run(replay(args.printers, args.clients))
        from kybercore import native  # type: ignore[import-untyped, unused-ignore]

        print(orjson.dumps({**result, "compiled": native.STATE.active}).decode())
        return
    trees = [args.kybercore_src, *args.compare_src]
    best: dict[Path, dict[str, Any]] = {}
    for _ in range(args.rounds):
        for src in trees:  # alternately, so a change of load hits every tree alike
            result = _child(src.resolve(), args.printers, args.clients)
            if src not in best or result["cpu_per_1000"] < best[src]["cpu_per_1000"]:
                best[src] = result
    for src in trees:
        print(orjson.dumps({"src": str(src), **best[src]}).decode())
    first = best[trees[0]]["cpu_per_1000"]
    summary = {str(src): round(best[src]["cpu_per_1000"] / first, 2) for src in trees}
    print(orjson.dumps({"relative_to_first": summary, "load": os.getloadavg()}).decode())


if __name__ == "__main__":
    main()
