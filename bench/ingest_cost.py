"""CPU per 1,000 Moonraker events: KyberCore against the floor, in the same run (issue 20).

``python -m bench.ingest_cost --printers N --clients M --seconds S`` runs, in order:

1. the *parse floor*, in this process: ``orjson.loads`` of the very frames the load
   generator sends (``notify_status_update``, ~250 bytes), CPU s per 1,000;
2. the load generator (:mod:`bench.loadgen`, LOAD GENERATOR — not Moonraker), N printers;
3. the *receive floor* (:mod:`bench.picows_floor`): a bare picows + orjson consumer of the
   same N streams, in a process of its own, CPU s per 1,000 events;
4. ``kybercore serve`` on the N printers, one per source tree given (``--kybercore-src``
   and ``--compare-src``) *side by side*, for ``--rounds``: started in turn and, once
   every printer of each is online, printing and settled, measured over the same S
   seconds, each with M browsers on ``/ws`` and its fleet read every 250 ms (the window
   of :mod:`bench.fleet_scale`, so the figure is the one issue 20 quotes): utime + stime
   over the updates the load generator wrote in the window (its log, not KyberCore's
   views: a backlog caught up would inflate those).

On a shared machine the load moves from minute to minute, and CPU seconds with it (caches
and hyperthreads are shared): trees measured side by side bear the same load, so their
ratio holds when the absolute figures do not. The goal (≤ 0.04 CPU s per 1,000 events at
N = 1,000) is judged on the first tree. Figures go to stdout and to
``bench/results/ingest_cost-<N>-<time>.json``.

With ``--deflate``, each tree is also measured, side by side, with browsers that offer
permessage-deflate as Chromium does: the cost of compressing every frame once per browser,
which the plain windows leave out.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import tempfile
import time
from pathlib import Path
from typing import Any, Final

import orjson
from rich.console import Console
from rich.table import Table

from bench import fleet_scale, procs
from bench.fleet_reader import FleetReader, ReadFailed
from bench.printer_model import SimPrinter

# kybercore ships no py.typed marker; mypy sees it as an untyped installed package.
from kybercore.registry.models import PrinterConfig  # type: ignore[import-untyped, unused-ignore]
from kybercore.registry.store import write_printers  # type: ignore[import-untyped, unused-ignore]

GOAL_PRINTERS: Final = 1_000
GOAL_CPU_PER_1000: Final = 0.04
# After start-up, the first seconds still carry its tail (retried reads, first renders).
SETTLE_SECONDS: Final = 5.0
PARSE_FRAMES: Final = 200_000
TICKS: Final = os.sysconf("SC_CLK_TCK")

Run = tuple[Path | None, bool]
"""A KyberCore measured: its source tree (None: the installed one), and whether its
browsers offer permessage-deflate."""


def parse_floor(frames: int = PARSE_FRAMES) -> dict[str, float]:
    """CPU s per 1,000 ``orjson.loads`` of the load generator's status frames."""
    printers = [SimPrinter(index) for index in range(100)]
    payloads = [
        orjson.dumps(
            {
                "jsonrpc": "2.0",
                "method": "notify_status_update",
                "params": [printers[i % 100].step(), time.monotonic()],
            }
        )
        for i in range(10_000)
    ]
    loads = orjson.loads
    rounds = max(1, frames // len(payloads))
    started = time.process_time()
    for _ in range(rounds):
        for payload in payloads:
            loads(payload)
    cpu = time.process_time() - started
    return {
        "frames": rounds * len(payloads),
        "frame_bytes": round(sum(map(len, payloads)) / len(payloads)),
        "cpu_per_1000": cpu / (rounds * len(payloads)) * 1000,
    }


async def _receive_floor(ports: list[int], seconds: float, work: Path) -> dict[str, Any]:
    ports_file = work / "ports.json"
    ports_file.write_bytes(orjson.dumps(ports))
    args = ["-m", "bench.picows_floor", "--ports-file", str(ports_file), "--seconds"]
    async with procs.child(*args, str(seconds)) as floor:
        timeout = seconds + 2 * fleet_scale._limit(len(ports)) + 10
        result: dict[str, Any] = await procs.read_json_line(floor, timeout)
    return result


def _times(pid: int) -> tuple[float, float]:
    """(utime, stime) in seconds from ``/proc/<pid>/stat``."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    return int(fields[11]) / TICKS, int(fields[12]) / TICKS


async def _window(
    pid: int, port: int, printers: int, clients: int, seconds: float, folder: Path, deflate: bool
) -> dict[str, Any]:
    """S seconds of M browsers on ``/ws`` (``deflate``: offering permessage-deflate) and a
    fleet read every 250 ms, as in :mod:`bench.fleet_scale`; KyberCore's CPU over exactly
    that time."""
    connect = fleet_scale._limit(printers) + clients
    args = ["-m", "bench.browsers", "--url", f"ws://127.0.0.1:{port}/ws", "--clients"]
    args += [str(clients), "--seconds", str(seconds + 2), "--connect-timeout", str(connect)]
    args += ["--deflate"] if deflate else []
    async with procs.child(*args, "--out", str(folder / "browsers.json")) as browsers:
        await procs.read_json_line(browsers, connect + 10)
        reader = FleetReader("127.0.0.1", port, fleet_scale.REQUEST_TIMEOUT)
        first: dict[str, int] | None = None
        last: dict[str, int] = {}
        before, started = _times(pid), time.monotonic()
        while time.monotonic() - started < seconds:
            sent = time.monotonic()
            with contextlib.suppress(ReadFailed):
                last = fleet_scale._durations(orjson.loads(await reader.get("/api/printers")))
                first = last if first is None else first
            await asyncio.sleep(max(0.0, fleet_scale.VIEW_POLL_SECONDS - (time.monotonic() - sent)))
        after, ended = _times(pid), time.monotonic()
        await reader.close()
        await asyncio.wait_for(browsers.wait(), connect)
    advance = sum(last[p] - first[p] for p in first if p in last) if first else 0
    return {
        "window": (started, ended),
        "utime": after[0] - before[0],
        "stime": after[1] - before[1],
        "ingested_in_views": advance,
    }


def _printers_file(folder: Path, ports: list[int]) -> Path:
    path = folder / "printers.json"
    write_printers(
        path,
        [
            PrinterConfig(
                id=f"p{index:05d}", name=f"Bench {index}", moonraker_url=f"http://127.0.0.1:{port}"
            )
            for index, port in enumerate(ports)
        ],
    )
    return path


async def _side_by_side(
    runs: list[Run], ports: list[int], clients: int, seconds: float, work: Path
) -> list[dict[str, Any]]:
    """One KyberCore per run (a tree, and whether its browsers deflate) on the same N
    printers at once: started one after the other, then measured in the same S seconds
    (each with its own M browsers and fleet reads). The machine's load moves from minute
    to minute; side by side, every run bears the same."""
    printers = len(ports)
    limit = 6 * fleet_scale._limit(printers)  # a loaded machine starts slowly
    async with contextlib.AsyncExitStack() as stack:
        running = []
        for index, (src, _) in enumerate(runs):
            folder = work / f"kc-{time.monotonic_ns()}-{index}"
            folder.mkdir()
            port = procs.free_port()
            log = folder / "kybercore.log"
            kybercore = fleet_scale.kybercore(_printers_file(folder, ports), log, port, src)
            pids, http = await stack.enter_async_context(kybercore)
            running.append((src, folder, port, pids["serve"], http))
            # One start-up at a time: 2 x N connections at once is a start-up benchmark.
            if await fleet_scale._wait_for(http, printers, fleet_scale._settled, limit) is None:
                return [{**_label(run), "settled": False} for run in runs]
        await asyncio.sleep(SETTLE_SECONDS)
        windows = await asyncio.gather(
            *(
                _window(pid, port, printers, clients, seconds, folder, deflate)
                for (_, deflate), (_, folder, port, pid, _) in zip(runs, running, strict=True)
            )
        )
    return [
        {**_label(run), "settled": True, **window}
        for run, window in zip(runs, windows, strict=True)
    ]


def _label(run: Run) -> dict[str, Any]:
    src, deflate = run
    return {"src": str(src or "installed"), "deflate": deflate}


def _figures(window: dict[str, Any], sent_log: dict[str, Any]) -> dict[str, Any]:
    """CPU per 1,000 of the updates the load generator wrote in the window (its own log,
    so a backlog KyberCore catches up with cannot inflate the count)."""
    if not window["settled"]:
        return window
    first_at, last_at = window.pop("window")
    events = sum(first_at <= t <= last_at for e in sent_log["printers"] for t in e["sent_at"])
    cpu = window["utime"] + window["stime"]
    return {
        **window,
        "events": events,
        "events_per_s": round(events / (last_at - first_at), 1),
        "ingested_ratio": round(window.pop("ingested_in_views") / max(events, 1), 3),
        "utime": round(window["utime"], 2),
        "stime": round(window["stime"], 2),
        "cpu_per_1000": cpu / max(events, 1) * 1000,
        "cores": round(cpu / (last_at - first_at), 2),
    }


async def run(
    printers: int,
    clients: int,
    seconds: float,
    trees: list[Path | None],
    rounds: int,
    deflate: bool = False,
) -> dict[str, Any]:
    """The whole run; returns the figures. ``deflate``: each tree measured with plain and
    with deflating browsers, side by side."""
    kinds = (False, True) if deflate else (False,)
    runs: list[Run] = [(tree, d) for tree in trees for d in kinds]
    load = os.getloadavg()
    results: dict[str, Any] = {
        "params": {
            "printers": printers,
            "clients": clients,
            "seconds": seconds,
            "deflate": deflate,
        },
        "load_average_before": [round(x, 2) for x in load],
        "parse_floor": parse_floor(),
        "kybercore": [],
    }
    with tempfile.TemporaryDirectory(prefix="kybercore-ingest-") as tmp:
        work = Path(tmp)
        args = ["-m", "bench.loadgen", "--printers", str(printers)]
        async with procs.child(*args, pipe_stdin=True) as loadgen:
            limit = fleet_scale._limit(printers)
            ports: list[int] = (await procs.read_json_line(loadgen, limit))["ports"]
            results["receive_floor"] = await _receive_floor(ports, seconds, work)
            windows = []
            for _ in range(rounds):
                windows += await _side_by_side(runs, ports, clients, seconds, work)
            await procs.command(loadgen, f"dump {work / 'sent.json'}", limit)
            sent_log = orjson.loads((work / "sent.json").read_bytes())
    results["kybercore"] = [_figures(window, sent_log) for window in windows]
    results["load_average_after"] = [round(x, 2) for x in os.getloadavg()]
    first = [w["cpu_per_1000"] for w in results["kybercore"][:: len(runs)] if w.get("cpu_per_1000")]
    results["goal"] = {
        "applies": printers == GOAL_PRINTERS,
        "limit": GOAL_CPU_PER_1000,
        "value": min(first) if first else None,
        "met": bool(first) and min(first) <= GOAL_CPU_PER_1000,
    }
    return results


_COMPILED = {True: "compiled", False: "pure Python"}


def show(results: dict[str, Any], console: Console) -> None:
    """The figures as one table."""
    params = results["params"]
    table = Table(
        title=f"CPU s per 1,000 events: {params['printers']:,} printers, "
        f"{params['clients']} browsers, {params['seconds']:g} s windows "
        "(LOAD GENERATOR — not Moonraker)"
    )
    columns = ("consumer", "events/s", "CPU s / 1,000 events", "user / sys", "x parse floor")
    for column in columns:
        table.add_column(column, justify="left" if column == "consumer" else "right")
    parse = results["parse_floor"]["cpu_per_1000"]
    receive = results["receive_floor"]
    rows: list[tuple[str, float | None, float | None, str]] = [
        ("parse floor: orjson.loads only", None, parse, ""),
        (
            "receive floor: picows + orjson",
            receive["events"] / receive["seconds"],
            receive["cpu_per_1000"],
            "",
        ),
    ]
    for window in results["kybercore"]:
        split = f"{window['utime']:.1f} / {window['stime']:.1f}" if window["settled"] else ""
        label = f"kybercore serve ({window['src']}, {_COMPILED[window['compiled']]})"
        label += ", browsers deflate" if window["deflate"] else ""
        rows.append((label, window.get("events_per_s"), window.get("cpu_per_1000"), split))
    for label, rate, cpu, split in rows:
        table.add_row(
            label,
            "—" if rate is None else f"{rate:,.0f}",
            "—" if cpu is None else f"{cpu:.4f}",
            split,
            "—" if cpu is None else f"{cpu / parse:,.1f}",
        )
    goal = results["goal"]
    if goal["applies"]:
        verdict = "[green]met[/green]" if goal["met"] else "[red]not met[/red]"
        value = "—" if goal["value"] is None else f"{goal['value']:.4f}"
        table.add_row(f"goal: ≤ {goal['limit']} at N = 1,000", "", f"{value}: {verdict}")
    console.print(table)


def main() -> None:
    """``python -m bench.ingest_cost --printers N --clients M --seconds S``."""
    parser = argparse.ArgumentParser(description="KyberCore ingest cost per event")
    parser.add_argument("--printers", type=int, default=GOAL_PRINTERS)
    parser.add_argument("--clients", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--kybercore-src", type=Path, help="the kybercore package under this src/")
    parser.add_argument(
        "--compare-src", type=Path, help="another src/ (e.g. the code before) measured in turn"
    )
    parser.add_argument(
        "--deflate", action="store_true", help="also measure browsers offering permessage-deflate"
    )
    parser.add_argument("--results-dir", type=Path, default=fleet_scale.RESULTS_DIR)
    args = parser.parse_args()
    if args.printers < 1 or args.clients < 1 or args.seconds <= 0 or args.rounds < 1:
        parser.error("--printers, --clients, --rounds must be >= 1, --seconds > 0")
    trees: list[Path | None] = [args.kybercore_src]
    if args.compare_src is not None:
        trees.append(args.compare_src)
    results = asyncio.run(
        run(args.printers, args.clients, args.seconds, trees, args.rounds, args.deflate)
    )
    compiled = {str(src or "installed"): procs.compiled(src) for src in trees}
    for window in results["kybercore"]:
        window["compiled"] = compiled[window["src"]]
    show(results, Console())
    args.results_dir.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = args.results_dir / f"ingest_cost-{args.printers}-{stamp}.json"
    path.write_bytes(orjson.dumps(results, option=orjson.OPT_INDENT_2))
    print(f"results: {path}")


if __name__ == "__main__":
    main()
