"""Turning raw measurements into figures, goals, a table and a JSON file. Pure, apart from
:func:`write` and :func:`show`."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson
from rich.console import Console
from rich.table import Table


def percentile(values: Sequence[float], pct: float) -> float | None:
    """Nearest-rank percentile of ``values`` (None when there are none)."""
    if not values:
        return None
    ordered = sorted(values)
    rank = max(1, math.ceil(pct / 100 * len(ordered)))
    return ordered[rank - 1]


def spread(values: Sequence[float], scale: float = 1.0) -> dict[str, float | None]:
    """p50/p95/p99/max of ``values`` times ``scale`` (1000: seconds to milliseconds)."""
    out: dict[str, float | None] = {}
    for name, pct in (("p50", 50.0), ("p95", 95.0), ("p99", 99.0), ("max", 100.0)):
        value = percentile(values, pct)
        out[name] = None if value is None else round(value * scale, 2)
    out["count"] = len(values)
    return out


def latencies(
    observations: Sequence[Mapping[str, Sequence[Any]]],
    sent: Mapping[str, tuple[int, Sequence[float]]],
) -> list[float]:
    """Seconds from the load generator's write to a browser's receipt, per observation.

    ``sent`` maps a printer id to (base, send times); a browser saw print duration ``value``,
    which is update ``value - base`` of that printer (see :mod:`bench.printer_model`).
    """
    out: list[float] = []
    for seen in observations:
        for printer_id, value, received in zip(
            seen["printer"], seen["value"], seen["t"], strict=True
        ):
            base, times = sent[printer_id]
            seq = int(value) - base
            if 1 <= seq <= len(times):
                out.append(received - times[seq - 1])
    return out


@dataclass(frozen=True)
class Goal:
    """A target from issue 7 (or 20), defined at one fleet size (and browser count)."""

    name: str
    path: tuple[str, ...]
    limit: float
    at_least: bool
    printers: int
    clients: int | None = None

    def applies(self, printers: int, clients: int) -> bool:
        """Whether this run is the scale the goal is set for."""
        return printers == self.printers and self.clients in (None, clients)


GOALS = (
    Goal("fleet view p99 <= 20 ms", ("fleet_view_ms", "p99"), 20.0, False, 1_000),
    Goal("event-to-browser p99 <= 250 ms", ("event_to_browser_ms", "p99"), 250.0, False, 1_000),
    Goal("bulk pause <= 1 s", ("bulk_pause", "seconds"), 1.0, False, 1_000),
    Goal("RSS <= 100 KB per printer", ("rss_kib_per_printer",), 100.0, False, 1_000),
    Goal(
        "event-to-browser p99 <= 250 ms",
        ("event_to_browser_ms", "p99"),
        250.0,
        False,
        5_000,
        100,
    ),
    Goal("ingest >= 0.5 x baseline", ("ingest_ratio",), 0.5, True, 5_000, 100),
    # Issue 20 (2 workers, 100 browsers showing 50 printers each; its latency goal is the one
    # above): ingest against the load generator's own rate in the same span.
    Goal("ingest >= 0.9 x load generator", ("ingest_vs_loadgen",), 0.9, True, 5_000, 100),
)


def _lookup(results: Mapping[str, Any], path: tuple[str, ...]) -> Any:
    value: Any = results
    for key in path:
        value = value.get(key) if isinstance(value, Mapping) else None
    return value


def goals(results: Mapping[str, Any], printers: int, clients: int) -> list[dict[str, Any]]:
    """The goals set for this scale, each with its measured value and met / not met."""
    out = []
    for goal in GOALS:
        if not goal.applies(printers, clients):
            continue
        value = _lookup(results, goal.path)
        met = value is not None and (value >= goal.limit if goal.at_least else value <= goal.limit)
        out.append({"goal": f"N={goal.printers:,}: {goal.name}", "value": value, "met": met})
    return out


_ROWS = (
    ("start-up: all online / settled (s)", ("startup_seconds",)),
    ("ingest, KyberCore (events/s)", ("ingest_events_per_s",)),
    ("ingest, bare baseline (events/s)", ("baseline", "events_per_s")),
    # Its connect wait is its own (60 s): on a busy machine it may count fewer printers.
    ("bare baseline: printers connected", ("baseline", "connected")),
    ("KyberCore / baseline", ("ingest_ratio",)),
    ("load generator sent (events/s)", ("loadgen", "events_per_s")),
    ("KyberCore / load generator", ("ingest_vs_loadgen",)),
    ("event-to-browser p50 / p95 / p99 (ms)", ("event_to_browser_ms",)),
    ("GET /api/printers p50 / p95 / p99 (ms)", ("fleet_view_ms",)),
    ("bulk pause of all printers (s)", ("bulk_pause", "seconds")),
    ("bulk pause results ok", ("bulk_pause", "ok")),
    ("RSS per printer (KiB)", ("rss_kib_per_printer",)),
    ("KyberCore CPU (cores busy)", ("cpu_cores",)),
    ("CPU s per 1,000 events", ("cpu_seconds_per_1000_events",)),
    ("… per process", ("cpu_seconds_per_1000_events_by_process",)),
    ("browser frames / resyncs", ("browsers",)),
    ("cores busy: KyberCore / load gen. / browsers / harness", ("cores_busy",)),
)


def _cell(value: Any) -> str:
    if isinstance(value, Mapping):
        if "p95" in value:
            return " / ".join(_cell(value[key]) for key in ("p50", "p95", "p99"))
        if "loadgen" in value:
            parts = ("kybercore", "loadgen", "browsers", "harness")
            return " / ".join(f"{value[key]:.2f}" for key in parts)
        if "frames" in value:
            return f"{value['frames']:,} / {value['resyncs']}"
        if "settled" in value:
            settled = _cell(value["settled"]) if value["settled"] else f"not in {value['limit']:g}"
            if value.get("online_at_limit") is not None:
                settled += f" ({value['online_at_limit']:,} online by then)"
            return f"{_cell(value['online'])} / {settled}"
        return ", ".join(f"{key} {_cell(item)}" for key, item in value.items())
    if isinstance(value, float):
        return f"{value:,.3g}" if value < 10 else f"{value:,.0f}"
    return "—" if value is None else str(value)


def show(results: Mapping[str, Any], console: Console) -> None:
    """Print the figures and the goals as a table."""
    params = results["params"]
    workers = params.get("workers") or 0
    mode = f"NATS, {workers} workers + 1 front" if workers else "one process (serve)"
    mode += ", compiled" if params.get("compiled") else ", pure Python"
    show = params.get("show") or 0
    browsers = f"{params['clients']} browsers" + (f" showing {show} each" if show else "")
    table = Table(
        title=f"KyberCore fleet scale, {mode}: {params['printers']:,} printers, "
        f"{browsers}, {params['seconds']:g} s "
        "(LOAD GENERATOR — not Moonraker)"
    )
    table.add_column("metric")
    table.add_column("value", justify="right")
    for label, path in _ROWS:
        table.add_row(label, _cell(_lookup(results, path)))
    for goal in results["goals"]:
        verdict = "[green]met[/green]" if goal["met"] else "[red]not met[/red]"
        table.add_row(f"goal {goal['goal']}", f"{_cell(goal['value'])}: {verdict}")
    if not results["goals"]:
        table.add_row("goals", "set at N=1,000 and N=5,000 (100 browsers) only")
    console.print(table)


def write(results: Mapping[str, Any], folder: Path) -> Path:
    """Save as ``<folder>/fleet_scale-<N>-<time>.json`` and ``latest.json``."""
    folder.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    data = orjson.dumps(results, option=orjson.OPT_INDENT_2)
    path = folder / f"fleet_scale-{results['params']['printers']}-{stamp}.json"
    path.write_bytes(data)
    (folder / "latest.json").write_bytes(data)
    return path
