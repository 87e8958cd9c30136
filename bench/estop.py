"""A bulk emergency stop of N printers: over the open WebSockets versus over HTTP, one run.

``python -m bench.estop --printers 1000 --rounds 3`` starts the load generator
(:mod:`bench.loadgen`, LOAD GENERATOR — not Moonraker) with N printers, then in this
process:

1. N :class:`~kybercore.moonraker.client.MoonrakerClient` sessions, one per printer, as
   ``kybercore serve`` holds them (every one subscribed, 4 status updates/s each arriving
   meanwhile), and N HTTP-only clients on the same shared HTTP pool;
2. ``rounds`` times, alternately: every printer e-stopped at once through the sessions
   (the WebSocket path, as KyberCore does it now), then through the HTTP-only clients
   (the shared pool, the path it took before): the wall time until all N have answered,
   and each stop's own latency;
3. with ``--api``, ``kybercore serve`` on the same printers and one
   ``POST /api/fleet/actions/emergency_stop`` naming all N, as an operator's "stop the
   room" button sends it (``--kybercore-src DIR`` serves it from another copy of the
   source, e.g. one from before e-stops took the socket, for a comparison).

Counts of HTTP requests prove which path each round took. Figures go to stdout and to
``bench/results/estop-<N>-<time>.json``.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, Final

import httpx
import orjson

from bench import procs
from bench.fleet_scale import RESULTS_DIR, _cancel_on_sigterm, _limit, _online, _wait_for, kybercore

# kybercore ships no py.typed marker; mypy sees it as an untyped installed package.
from kybercore.moonraker.client import MoonrakerClient  # type: ignore[import-untyped, unused-ignore]
from kybercore.moonraker.http import new_http_client  # type: ignore[import-untyped, unused-ignore]
from kybercore.registry.models import PrinterConfig  # type: ignore[import-untyped, unused-ignore]
from kybercore.registry.store import write_printers  # type: ignore[import-untyped, unused-ignore]

BULK_TIMEOUT: Final = 120.0


async def _bulk(stops: list[Callable[[], Awaitable[None]]]) -> dict[str, Any]:
    """Run every stop at once: wall seconds until all answered, and per-stop latencies."""
    latencies: list[float] = []
    failures: list[str] = []

    async def one(stop: Callable[[], Awaitable[None]]) -> None:
        started = time.monotonic()
        try:
            await stop()
        except Exception as exc:  # a failed stop is a figure, not a crash of the run
            failures.append(f"{type(exc).__name__}: {exc}")
        else:
            latencies.append(time.monotonic() - started)

    started = time.monotonic()
    tasks = [asyncio.ensure_future(one(stop)) for stop in stops]
    _done, late = await asyncio.wait(tasks, timeout=BULK_TIMEOUT)
    for task in late:
        task.cancel()
    await asyncio.gather(*late, return_exceptions=True)
    wall = time.monotonic() - started
    ordered = sorted(latencies) or [float("nan")]
    return {
        "wall_s": round(wall, 3),
        "ok": len(latencies),
        "failed": len(failures),
        "unanswered_after_timeout": len(late),
        "first_failure": failures[0] if failures else None,
        "latency_ms": {
            "p50": round(1000 * statistics.median(ordered), 1),
            "p95": round(1000 * ordered[int(0.95 * (len(ordered) - 1))], 1),
            "max": round(1000 * ordered[-1], 1),
        },
    }


async def _paths(urls: list[str], rounds: int) -> dict[str, Any]:
    """Sessions vs HTTP-only clients, alternately, ``rounds`` times each."""
    http_requests = 0

    async def count(_request: httpx.Request) -> None:
        nonlocal http_requests
        http_requests += 1

    http = new_http_client()
    http.event_hooks["request"].append(count)
    connected = 0

    def on_event(_event: object) -> None:
        """Events are consumed as ``kybercore serve`` would receive them, then dropped."""

    sessions = [
        MoonrakerClient(url, http, name=f"p{i}", on_event=on_event) for i, url in enumerate(urls)
    ]
    plain = [MoonrakerClient(url, http, name=f"p{i}") for i, url in enumerate(urls)]
    results: dict[str, Any] = {"socket": [], "http": []}
    try:
        for client in sessions:
            client.start()
        deadline = time.monotonic() + 2 * _limit(len(urls))
        while (connected := sum(c.session.connected for c in sessions)) < len(urls):
            if time.monotonic() > deadline:
                raise RuntimeError(f"only {connected} of {len(urls)} sessions connected")
            await asyncio.sleep(0.2)  # poll: wait for every session, deadline above
        for _ in range(rounds):
            for path, clients in (("socket", sessions), ("http", plain)):
                before = http_requests
                figures = await _bulk([c.emergency_stop for c in clients])
                figures["http_requests"] = http_requests - before
                results[path].append(figures)
                print(f"{path}: {figures}", file=sys.stderr, flush=True)
    finally:
        await asyncio.gather(*(c.close() for c in sessions))
        await http.aclose()
    return results


async def _through_api(urls: list[str], work: Path, src: Path | None) -> dict[str, Any]:
    """``kybercore serve`` on the printers; one bulk e-stop of all of them over the API."""
    ids = [f"p{index:05d}" for index in range(len(urls))]
    printers_file = work / "printers.json"
    write_printers(
        printers_file,
        [
            PrinterConfig(id=pid, name=pid, moonraker_url=url)
            for pid, url in zip(ids, urls, strict=True)
        ],
    )
    async with kybercore(printers_file, work / "kybercore.log", procs.free_port(), src) as (
        _process,
        http,
    ):
        online = await _wait_for(http, len(ids), _online, 2 * _limit(len(ids)))
        if online is None:
            return {"online": None}
        started = time.monotonic()
        response = await http.post(
            "/api/fleet/actions/emergency_stop", json={"printer_ids": ids}, timeout=BULK_TIMEOUT
        )
        wall = time.monotonic() - started
        results = response.json().get("results", []) if response.status_code == 200 else []
    return {
        "online_s": online,
        "wall_s": round(wall, 3),
        "http_status": response.status_code,
        "ok": sum(1 for r in results if r["ok"]),
    }


async def run(printers: int, rounds: int, api: bool, src: Path | None) -> dict[str, Any]:
    """The whole measurement; returns the figures."""
    with tempfile.TemporaryDirectory(prefix="kybercore-estop-") as tmp:
        args = ["-m", "bench.loadgen", "--printers", str(printers)]
        async with procs.child(*args, pipe_stdin=True) as loadgen:
            ports = (await procs.read_json_line(loadgen, _limit(printers)))["ports"]
            urls = [f"http://127.0.0.1:{port}" for port in ports]
            results = {"printers": printers, "rounds": rounds, **await _paths(urls, rounds)}
            if api:
                results["api"] = await _through_api(urls, Path(tmp), src)
    return results


def _summary(results: dict[str, Any]) -> str:
    lines = [f"bulk e-stop of {results['printers']} printers (load generator, loopback):"]
    for path in ("socket", "http"):
        for n, figures in enumerate(results[path], 1):
            latency = figures["latency_ms"]
            lines.append(
                f"  {path:6} round {n}: all answered in {figures['wall_s']:.3f} s; per stop "
                f"p50 {latency['p50']} ms, p95 {latency['p95']} ms, max {latency['max']} ms; "
                f"{figures['ok']} ok, {figures['failed']} failed; "
                f"{figures['http_requests']} HTTP requests"
            )
    if "api" in results:
        lines.append(
            f"  through the API (POST /api/fleet/actions/emergency_stop): {results['api']}"
        )
    return "\n".join(lines)


def main() -> None:
    """``python -m bench.estop --printers N --rounds R [--api]``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--printers", type=int, default=1000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--api", action="store_true", help="also through kybercore serve")
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    parser.add_argument(
        "--kybercore-src",
        type=Path,
        help="serve the API from the kybercore package under this folder (e.g. an older src/)",
    )
    args = parser.parse_args()
    work = run(args.printers, args.rounds, args.api, args.kybercore_src)
    results = asyncio.run(_cancel_on_sigterm(work))
    print(_summary(results))
    args.results_dir.mkdir(parents=True, exist_ok=True)
    path = args.results_dir / f"estop-{args.printers}-{int(time.time())}.json"
    path.write_bytes(orjson.dumps(results, option=orjson.OPT_INDENT_2))
    print(f"results: {path}")


if __name__ == "__main__":
    main()
