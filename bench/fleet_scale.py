"""KyberCore at fleet scale: N load-generated printers, M browsers, one bare baseline.

``python -m bench.fleet_scale --printers N --clients M --seconds S`` runs, in order:

1. the load generator (:mod:`bench.loadgen`, LOAD GENERATOR — not Moonraker), a process
   serving N printers on loopback;
2. the baseline (:mod:`bench.baseline`): a bare ``websockets`` + ``json.loads`` loop over
   the same N streams for S seconds, in a process of its own — the ceiling;
3. an idle KyberCore (no printers) for the memory baseline;
4. ``kybercore serve`` on the N printers, timed until every printer is online and printing,
   then until its file metadata and configfile limits are loaded (start-up traffic done);
   one that has not settled within the limit is reported so and not measured further;
5. S seconds with M browsers on ``/ws`` (:mod:`bench.browsers`, another process) while this
   process polls ``GET /api/printers`` every 250 ms, as a dashboard or script would
   (:mod:`bench.fleet_reader`, a bare HTTP/1.1 client, so its latency is KyberCore's);
   every browser gets the whole fleet in full, or, with ``--show K``, shows a page of K
   printers (browser i: printers i*K… modulo N) and gets slim summaries of the rest;
6. a bulk pause of all N printers through ``POST /api/fleet/actions/pause``.

Each phase runs once and alone, so the processes share the 2 cores only as they would in
use. Figures go to stdout (a table, goals met / not met) and to ``bench/results/``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import platform
import signal
import tempfile
import time
from collections.abc import AsyncIterator, Callable, Coroutine
from pathlib import Path
from typing import Any, Final

import httpx
import orjson
from rich.console import Console

from bench import procs, report
from bench.cluster import kybercore_cluster
from bench.fleet_reader import FleetReader, ReadFailed

# kybercore ships no py.typed marker; mypy sees it as an untyped installed package.
from kybercore.registry.models import PrinterConfig  # type: ignore[import-untyped, unused-ignore]
from kybercore.registry.store import write_printers  # type: ignore[import-untyped, unused-ignore]

RESULTS_DIR: Final = Path(__file__).parent / "results"
VIEW_POLL_SECONDS: Final = 0.25
# A fleet request slower than this counts as failed; the bulk pause gets longer.
REQUEST_TIMEOUT: Final = 10.0
PAUSE_TIMEOUT: Final = 120.0


def _limit(printers: int) -> float:
    """Seconds a start-up step may take at this fleet size before the run is abandoned."""
    return 30.0 + printers / 50


async def _baseline(ports: list[int], seconds: float, work: Path) -> dict[str, Any]:
    """The bare loop's figures over the same streams (:mod:`bench.baseline`)."""
    ports_file = work / "ports.json"
    ports_file.write_bytes(orjson.dumps(ports))
    args = ["-m", "bench.baseline", "--ports-file", str(ports_file), "--seconds", str(seconds)]
    async with procs.child(*args) as baseline:
        result: dict[str, Any] = await procs.read_json_line(
            baseline, seconds + 2 * _limit(len(ports))
        )
    return result


async def _idle_rss(work: Path, src: Path | None) -> int:
    """VmRSS of a KyberCore serving no printer, after one fleet request."""
    path = work / "idle" / "printers.json"
    path.parent.mkdir()
    write_printers(path, [])
    log = work / "idle" / "kybercore.log"
    async with kybercore(path, log, procs.free_port(), src) as (pids, http):
        await _wait_for(http, 0, lambda view: True, _limit(0))
        return procs.rss_kib(pids["serve"])


@contextlib.asynccontextmanager
async def kybercore(
    printers_file: Path, log: Path, port: int, src: Path | None
) -> AsyncIterator[tuple[dict[str, int], httpx.AsyncClient]]:
    """``kybercore serve`` on ``port`` in a subprocess (``{"serve": pid}``), and an HTTP
    client pointed at it.

    ``src``: run the ``kybercore`` package found there instead of the installed one.
    """
    args = ["-m", "kybercore", "serve", "--port", str(port), "--printers-file", str(printers_file)]
    env = {**os.environ, "PYTHONPATH": str(src)} if src else None
    with log.open("wb") as log_file:
        async with (
            procs.child(*args, log=log_file, env=env) as process,
            httpx.AsyncClient(
                base_url=f"http://127.0.0.1:{port}", trust_env=False, timeout=REQUEST_TIMEOUT
            ) as http,
        ):
            yield {"serve": process.pid}, http


def _online(view: dict[str, Any]) -> bool:
    """Connected over the WebSocket and printing."""
    return bool(view["connection"] == "online" and view["job"]["state"] == "printing")


def _settled(view: dict[str, Any]) -> bool:
    """Online, and the start-up HTTP fetches (file metadata, configfile limits) are done."""
    return (
        _online(view)
        and view["job"]["estimated_time"] is not None
        and view["capabilities"]["build_volume"] is not None
    )


async def _wait_for(
    http: httpx.AsyncClient, printers: int, ready: Callable[[dict[str, Any]], bool], limit: float
) -> float | None:
    """Seconds until KyberCore answers with all ``printers`` ``ready``; None past ``limit``."""
    started = time.monotonic()
    while time.monotonic() - started < limit:
        with contextlib.suppress(httpx.TransportError):  # not listening yet, or too busy
            response = await http.get("/api/printers")
            if response.status_code == 200 and sum(map(ready, response.json())) == printers:
                return round(time.monotonic() - started, 1)
        await asyncio.sleep(0.5)
    return None


async def _count(http: httpx.AsyncClient, ready: Callable[[dict[str, Any]], bool]) -> int | None:
    """How many printers are ``ready`` now; None if KyberCore does not answer. Read once a
    wait has run out, so that a report says how far start-up got."""
    with contextlib.suppress(httpx.TransportError):
        response = await http.get("/api/printers")
        if response.status_code == 200:
            return sum(map(ready, response.json()))
    return None


def _durations(views: list[dict[str, Any]]) -> dict[str, int]:
    return {view["id"]: view["job"]["print_duration"] for view in views}


def pages(ids: list[str], clients: int, show: int) -> list[list[str]]:
    """The printers each browser shows: browser i the K = ``show`` printers from i*K on,
    wrapping around the fleet (100 browsers x 50 cover 5,000 printers once)."""
    return [[ids[(i * show + j) % len(ids)] for j in range(show)] for i in range(clients)]


async def _measure(
    pids: tuple[dict[str, int], int],
    http: httpx.AsyncClient,
    ws_url: str,
    fleet: tuple[list[str], int, int],
    seconds: float,
    work: Path,
) -> dict[str, Any]:
    """The measured window: browsers listening, the fleet view polled, CPU and RSS read.
    ``pids``: KyberCore's processes by role, and the load generator's; ``fleet``: the
    printer ids, the browsers and how many printers each shows (0: all, in full)."""
    mine, loadgen_pid = pids
    ids, clients, show = fleet
    printers = len(ids)
    out = work / "browsers.json"
    # Every browser first gets a snapshot of the whole fleet (~1 KB per printer).
    connect = _limit(printers) + clients
    args = ["--url", ws_url, "--clients", str(clients), "--seconds", str(seconds)]
    args += ["--connect-timeout", str(connect), "--out", str(out)]
    if show:
        views = work / "views.json"
        views.write_bytes(orjson.dumps(pages(ids, clients, show)))
        args += ["--views", str(views)]
    async with procs.child("-m", "bench.browsers", *args) as browsers:
        hello = await procs.read_json_line(browsers, connect + 10)
        # Every process's share of the 2 cores in the window: what KyberCore competes with.
        # (The browsers process exits at the end of the window; it reports its own.)
        shares = {"loadgen": loadgen_pid, "harness": os.getpid()}
        others = {name: procs.cpu_seconds(p) for name, p in shares.items()}
        each = {role: procs.cpu_seconds(p) for role, p in mine.items()}
        view_times: list[float] = []
        polls: list[tuple[float, dict[str, int]]] = []
        failures = 0
        reader = FleetReader(http.base_url.host, http.base_url.port or 80, REQUEST_TIMEOUT)
        started = time.monotonic()
        while time.monotonic() - started < seconds:
            sent = time.monotonic()
            try:
                body: bytes | None = await reader.get("/api/printers")
            except ReadFailed:
                body = None
                failures += 1  # counted at the time it took to give up
            # Latency ends with the last byte of the body: parsing it here is this
            # process's cost, not KyberCore's (~13 ms for 1,000 printers).
            elapsed = time.monotonic() - sent
            view_times.append(elapsed)
            if body is not None:
                polls.append((sent, _durations(orjson.loads(body))))
            await asyncio.sleep(max(0.0, VIEW_POLL_SECONDS - (time.monotonic() - sent)))
        await reader.close()
        each = {role: procs.cpu_seconds(p) - each[role] for role, p in mine.items()}
        cpu = sum(each.values())
        cpu_window = time.monotonic() - started
        others = {name: procs.cpu_seconds(p) - others[name] for name, p in shares.items()}
        rss = sum(procs.rss_kib(p) for p in mine.values())
        await asyncio.wait_for(browsers.wait(), connect)
    received = orjson.loads(out.read_bytes())
    measured = {
        "window": (started, time.monotonic()),
        "ingest_events_per_s": None,
        "cpu_seconds": cpu,
        "cpu_seconds_by_process": each,
        "cpu_window": cpu_window,
        "cores_busy": {
            "kybercore": round(cpu / cpu_window, 2),
            **{name: round(used / cpu_window, 2) for name, used in others.items()},
            "browsers": round(received.pop("cpu_seconds") / seconds, 2),
        },
        "rss_kib": rss,
        "fleet_view_ms": {**report.spread(view_times, 1000), "failed": failures},
        "observations": received.pop("observations"),
        "browsers": {"connected": hello["connected"], **received},
    }
    # Every update bumps print_duration by one: its advance is the count ingested. When the
    # fleet view did not answer twice, a measuring browser's first and last sight of each
    # printer gives the same count (later, as it passed through the hub) — unless browsers
    # show pages: one then sees only its page's durations, not the fleet's.
    first_at, last_at, events = _advance(polls)
    if events is None and measured["observations"] and not show:
        first_at, last_at, events = _advance(_sightings(measured["observations"][0]))
    if events is not None:
        measured["window"] = (first_at, last_at)
        measured["ingest_events_per_s"] = events / (last_at - first_at)
    return measured


def _advance(
    reads: list[tuple[float, dict[str, int]]],
) -> tuple[float, float, int | None]:
    """Total print-duration advance between the first and last of timed fleet reads."""
    if len(reads) < 2 or reads[-1][0] <= reads[0][0]:
        return 0.0, 0.0, None
    (first_at, first), (last_at, last) = reads[0], reads[-1]
    return first_at, last_at, sum(last[pid] - first[pid] for pid in first if pid in last)


def _sightings(seen: dict[str, list[Any]]) -> list[tuple[float, dict[str, int]]]:
    """One browser's observations as two fleet reads: each printer as first and last seen,
    at the mean times of those sightings."""
    first: dict[str, tuple[float, int]] = {}
    last: dict[str, tuple[float, int]] = {}
    for printer, value, received in zip(seen["printer"], seen["value"], seen["t"], strict=True):
        first.setdefault(printer, (received, value))
        last[printer] = (received, value)
    if not first:
        return []
    return [
        (sum(t for t, _ in first.values()) / len(first), {p: v for p, (_, v) in first.items()}),
        (sum(t for t, _ in last.values()) / len(last), {p: v for p, (_, v) in last.items()}),
    ]


async def _bulk_pause(http: httpx.AsyncClient, ids: list[str]) -> dict[str, Any]:
    """Pause every printer in one request; wall time until all results are back."""
    started = time.monotonic()
    try:
        response = await http.post(
            "/api/fleet/actions/pause", json={"printer_ids": ids}, timeout=PAUSE_TIMEOUT
        )
    except httpx.TimeoutException:
        return {"seconds": None, "timed_out_after": PAUSE_TIMEOUT, "ok": 0, "failed": len(ids)}
    elapsed = time.monotonic() - started
    results = response.json().get("results", []) if response.status_code == 200 else []
    failed = [r for r in results if not r["ok"]]
    return {
        "seconds": round(elapsed, 3),
        "http_status": response.status_code,
        "ok": len(results) - len(failed),
        "failed": len(failed) + len(ids) - len(results),
        "first_failure": failed[0]["message"] if failed else None,
    }


async def run(
    printers: int,
    clients: int,
    seconds: float,
    src: Path | None = None,
    workers: int = 0,
    show: int = 0,
) -> dict[str, Any]:
    """One full benchmark run; returns the figures (see :mod:`bench.report`). With
    ``workers``, KyberCore runs distributed (:mod:`bench.cluster`) instead of ``serve``;
    with ``show``, each browser shows a page of that many printers (0: all in full)."""
    load = os.getloadavg()
    ids = [f"p{index:05d}" for index in range(printers)]
    with tempfile.TemporaryDirectory(prefix="kybercore-bench-") as tmp:
        work = Path(tmp)
        loadgen_args = ["-m", "bench.loadgen", "--printers", str(printers)]
        async with procs.child(*loadgen_args, pipe_stdin=True) as loadgen:
            ports: list[int] = (await procs.read_json_line(loadgen, _limit(printers)))["ports"]
            baseline = await _baseline(ports, seconds, work)
            idle_rss = await _idle_rss(work, src)
            printers_file = work / "printers.json"
            write_printers(
                printers_file,
                [
                    PrinterConfig(
                        id=pid, name=f"Bench {pid}", moonraker_url=f"http://127.0.0.1:{port}"
                    )
                    for pid, port in zip(ids, ports, strict=True)
                ],
            )
            port = procs.free_port()
            log = work / "kybercore.log"
            measured: dict[str, Any] | None = None
            pause = None
            launch = (
                kybercore_cluster(printers_file, work, port, workers, src, REQUEST_TIMEOUT)
                if workers
                else kybercore(printers_file, log, port, src)
            )
            async with launch as (kybercore_pids, http):
                online = await _wait_for(http, printers, _online, 2 * _limit(printers))
                settled = await _wait_for(http, printers, _settled, 2 * _limit(printers))
                at_limit = None if settled is not None else await _count(http, _online)
                # Measuring a KyberCore still busy starting up would time its start-up.
                if settled is not None:
                    ws_url = f"ws://127.0.0.1:{port}/ws"
                    fleet = (ids, clients, show)
                    pids = (kybercore_pids, loadgen.pid)
                    measured = await _measure(pids, http, ws_url, fleet, seconds, work)
                    pause = await _bulk_pause(http, ids)
            await procs.command(loadgen, f"dump {work / 'sent.json'}", _limit(printers))
            sent_log = orjson.loads((work / "sent.json").read_bytes())
    results: dict[str, Any] = {
        "params": {
            "printers": printers,
            "clients": clients,
            "seconds": seconds,
            "workers": workers,
            "show": show,
            "kybercore_src": str(src) if src else "installed",
            "compiled": procs.compiled(src),
        },
        "host": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_average_before": [round(x, 2) for x in load],
        },
        "startup_seconds": {
            "online": online,
            "settled": None if settled is None else (online or 0) + settled,
            "limit": 2 * _limit(printers),
            # When start-up did not finish: printers online and printing after both waits.
            "online_at_limit": at_limit,
        },
        "baseline": baseline,
        "idle_rss_kib": idle_rss,
    }
    if measured is not None:
        results.update(_figures(measured, sent_log, ids, idle_rss, baseline))
        results["bulk_pause"] = pause
    results["goals"] = report.goals(results, printers, clients)
    return results


def _figures(
    measured: dict[str, Any],
    sent_log: dict[str, Any],
    ids: list[str],
    idle_rss: int,
    baseline: dict[str, Any],
) -> dict[str, Any]:
    """The measured window's figures, latencies joined with the load generator's log."""
    sent = {
        pid: (entry["base"], entry["sent_at"])
        for pid, entry in zip(ids, sent_log["printers"], strict=True)
    }
    first_at, last_at = measured["window"]
    emitted = sum(
        first_at <= t <= last_at for entry in sent_log["printers"] for t in entry["sent_at"]
    )
    ingest = measured["ingest_events_per_s"]
    sent_rate = emitted / (last_at - first_at)
    return {
        "ingest_events_per_s": None if ingest is None else round(ingest, 1),
        "ingest_ratio": None if ingest is None else round(ingest / baseline["events_per_s"], 3),
        # Issue 20's measure: what KyberCore consumed of what was written in the same span.
        "ingest_vs_loadgen": None
        if ingest is None or not sent_rate
        else round(ingest / sent_rate, 3),
        "loadgen": {
            "events_per_s": round(sent_rate, 1),
            "emit_lag_ms": report.spread(sent_log["lags"], 1000),
        },
        "event_to_browser_ms": report.spread(
            report.latencies(measured["observations"], sent), 1000
        ),
        "fleet_view_ms": measured["fleet_view_ms"],
        "rss_kib": measured["rss_kib"],
        "rss_kib_per_printer": round((measured["rss_kib"] - idle_rss) / len(ids), 1),
        "cpu_seconds": round(measured["cpu_seconds"], 2),
        # Cores in use, and CPU per update: ingest is a rate, so both use the CPU's window.
        "cpu_cores": round(measured["cpu_seconds"] / measured["cpu_window"], 2),
        "cpu_seconds_per_1000_events": None
        if ingest is None
        else round(measured["cpu_seconds"] / (ingest * measured["cpu_window"]) * 1000, 4),
        # Per process (serve; or each worker, the front and nats-server): what it costs.
        "cpu_seconds_per_1000_events_by_process": None
        if ingest is None
        else {
            role: round(used / (ingest * measured["cpu_window"]) * 1000, 4)
            for role, used in measured["cpu_seconds_by_process"].items()
        },
        "browsers": measured["browsers"],
        "cores_busy": measured["cores_busy"],
    }


async def _cancel_on_sigterm(work: Coroutine[Any, Any, dict[str, Any]]) -> dict[str, Any]:
    """Run ``work``; SIGTERM cancels it, so every child process is still stopped."""
    task = asyncio.ensure_future(work)
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, task.cancel)
    return await task


def main() -> None:
    """``python -m bench.fleet_scale --printers N --clients M --seconds S``."""
    parser = argparse.ArgumentParser(description="KyberCore fleet-scale benchmark")
    parser.add_argument("--printers", type=int, default=100)
    parser.add_argument("--clients", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    parser.add_argument(
        "--workers",
        type=int,
        default=0,
        help="also run KyberCore on NATS with this many ingest workers and one front, after "
        "the single process, on the same load (side by side in one report)",
    )
    parser.add_argument(
        "--kybercore-src",
        type=Path,
        help="benchmark the kybercore package under this folder (e.g. a patched copy's src/)",
    )
    parser.add_argument(
        "--show",
        type=int,
        default=0,
        help="each browser shows a page of this many printers (full views; slim summaries of "
        "the rest), browser i from printer i*K on; default: every browser gets all in full",
    )
    args = parser.parse_args()
    if args.printers < 1 or args.clients < 1 or args.seconds <= 0:
        parser.error("--printers and --clients must be >= 1, --seconds > 0")
    if not 0 <= args.show <= args.printers:
        parser.error("--show must be between 0 and --printers")
    modes = [0, args.workers] if args.workers else [0]
    for workers in modes:
        results = asyncio.run(
            _cancel_on_sigterm(
                run(
                    args.printers,
                    args.clients,
                    args.seconds,
                    args.kybercore_src,
                    workers,
                    args.show,
                )
            )
        )
        report.show(results, Console())
        print(f"results: {report.write(results, args.results_dir)}")


if __name__ == "__main__":
    main()
