"""``/metrics`` in Prometheus' text format, from what KyberCore already holds in memory.

A scrape reads the published printer views (the very ones ``GET /api/printers`` answers
with), the job counts and queue figures (kept up to date as they are written and polled,
:mod:`.figures`), and a few counters: it never asks a printer or the database anything.
They are copied on the event loop (:class:`Snapshot`) and formatted in a worker thread.

The :class:`Source` on ``serve`` is the ledger; on a front on NATS it is
:class:`kybercore.scale.front_metrics.FrontMetrics`, from the views the front follows. A
view whose connection is ``stale`` (a front's printer that no worker reports now) is
counted under that connection, and its heaters and progress, the last its owner sent, are
left out: they are not the printer's now.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, Final, Protocol

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

HEATERS = ("extruder", "bed")
"""The heaters of a printer view (``bed`` is Klipper's ``heater_bed``)."""
STALE: Final = "stale"
"""The connection of a front's view whose owner has gone silent."""


@dataclass(frozen=True)
class QueueFigures:
    """The queue's depth, as last read from its tables."""

    jobs: int = 0
    """Jobs queued (copies left to print or in flight)."""
    copies_left: int = 0
    """Copies nobody is printing yet."""
    oldest: float | None = None
    """When the oldest queued job was queued (epoch seconds)."""

    @classmethod
    def of(cls, jobs: int, copies_left: int, oldest: Any) -> QueueFigures:
        """From the values a query returns (``oldest`` a datetime, naive meaning UTC)."""
        when: float | None = None
        if isinstance(oldest, datetime):
            when = (oldest if oldest.tzinfo else oldest.replace(tzinfo=UTC)).timestamp()
        elif isinstance(oldest, int | float):
            when = float(oldest)
        return cls(jobs, copies_left, when)


@dataclass(frozen=True)
class Snapshot:
    """What a scrape shows, copied on the event loop: plain data a worker thread may read
    while the loop goes on (formatting 1,000 printers takes over 100 ms)."""

    views: list[dict[str, Any]]
    """The published printer views (never modified once published)."""
    states: dict[str, str]
    jobs: dict[tuple[str, str], int]
    queue: QueueFigures
    reconnects: dict[str, int]
    browsers: int
    loop_lag: float
    workers: dict[str, tuple[int, float]] = field(default_factory=dict)
    """On a front on NATS: each worker reporting fresh slots, as (slots, its loop's lag)."""
    broker_connected: bool | None = None
    """On a front on NATS: whether it is connected to the broker now; None on serve."""


class Source(Protocol):
    """What ``/metrics`` reads: the ledger on ``serve``, the front's figures on NATS."""

    def metrics(self) -> Snapshot:
        """What ``/metrics`` shows now (a copy: format it anywhere)."""


def exposition(snapshot: Snapshot) -> bytes:
    """The snapshot in Prometheus' text format."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Collector(snapshot))
    return generate_latest(registry)


class _Collector(Collector):
    def __init__(self, snapshot: Snapshot) -> None:
        self._snapshot = snapshot

    def collect(self) -> Iterator[Metric]:
        snapshot = self._snapshot
        yield from _printer_metrics(snapshot.views)
        states = GaugeMetricFamily(
            "kybercore_printer_state",
            "1 for the printer's state in the ledger's timeline (on a front on NATS: as its "
            "owner's timeline names it from its view, or stale while no worker reports it)",
            labels=["printer", "state"],
        )
        for printer, state in sorted(snapshot.states.items()):
            states.add_metric([printer, state], 1)
        yield states
        jobs = CounterMetricFamily(
            "kybercore_jobs",
            "Printed jobs in the ledger, by printer and Moonraker outcome",
            labels=["printer", "outcome"],
        )
        for (printer, outcome), count in sorted(snapshot.jobs.items()):
            jobs.add_metric([printer, outcome], count)
        yield jobs
        yield from _queue_metrics(snapshot.queue)
        reconnects = CounterMetricFamily(
            "kybercore_moonraker_reconnects",
            "Times a printer's Moonraker session came back online after being online, "
            "counted where the session is held (none on a front on NATS: its workers hold "
            "them)",
            labels=["printer"],
        )
        for printer, count in sorted(snapshot.reconnects.items()):
            reconnects.add_metric([printer], count)
        yield reconnects
        yield GaugeMetricFamily(
            "kybercore_browser_clients",
            "Browser WebSockets connected to /ws",
            value=snapshot.browsers,
        )
        yield GaugeMetricFamily(
            "kybercore_event_loop_lag_seconds",
            "How late the event loop last ran a timer (0.5 s period)",
            value=snapshot.loop_lag,
        )
        yield from _worker_metrics(snapshot.workers)
        if snapshot.broker_connected is not None:
            yield GaugeMetricFamily(
                "kybercore_broker_connected",
                "1 while this front is connected to the NATS broker; 0 while cut off, when "
                "its printers turn stale and its actions are refused (none on serve)",
                value=int(snapshot.broker_connected),
            )


def _worker_metrics(workers: dict[str, tuple[int, float]]) -> Iterator[Metric]:
    slots = GaugeMetricFamily(
        "kybercore_worker_slots",
        "Slots an ingest worker reports fresh, as this front hears them (none on serve)",
        labels=["worker"],
    )
    lag = GaugeMetricFamily(
        "kybercore_worker_event_loop_lag_seconds",
        "How late an ingest worker's event loop runs, by its latest message: past about 1 s "
        "its printers turn stale (none on serve)",
        labels=["worker"],
    )
    for worker, (count, seconds) in sorted(workers.items()):
        slots.add_metric([worker], count)
        lag.add_metric([worker], seconds)
    yield slots
    yield lag


def _printer_metrics(views: list[dict[str, Any]]) -> Iterator[Metric]:
    counts = Counter((str(v["connection"]), str(v["klippy_state"])) for v in views)
    printers = GaugeMetricFamily(
        "kybercore_printers",
        "Printers by connection and Klippy state (connection stale: on a front on NATS, "
        "no worker reports the printer now; its Klippy state is the last reported)",
        labels=["connection", "klippy_state"],
    )
    for (connection, klippy), count in sorted(counts.items()):
        printers.add_metric([connection, klippy], count)
    yield printers
    temperature = GaugeMetricFamily(
        "kybercore_heater_temperature_celsius",
        "A heater's temperature",
        labels=["printer", "heater"],
    )
    target = GaugeMetricFamily(
        "kybercore_heater_target_celsius", "A heater's target", labels=["printer", "heater"]
    )
    progress = GaugeMetricFamily(
        "kybercore_print_progress_ratio",
        "Progress of the printer's current or last print, 0 to 1",
        labels=["printer", "state"],
    )
    for view in views:
        if view["connection"] == STALE:
            continue
        printer = str(view["id"])
        for heater in HEATERS:
            reading = view.get(heater) or {}
            if reading.get("temperature") is not None:
                temperature.add_metric([printer, heater], reading["temperature"])
            if reading.get("target") is not None:
                target.add_metric([printer, heater], reading["target"])
        job = view.get("job") or {}
        progress.add_metric([printer, str(job.get("state") or "")], job.get("progress") or 0.0)
    yield temperature
    yield target
    yield progress


def _queue_metrics(queue: QueueFigures) -> Iterator[Metric]:
    yield GaugeMetricFamily("kybercore_queue_jobs", "Jobs in the queue", value=queue.jobs)
    yield GaugeMetricFamily(
        "kybercore_queue_copies_left",
        "Copies queued that no printer is printing yet",
        value=queue.copies_left,
    )
    waited = 0.0 if queue.oldest is None else max(0.0, time.time() - queue.oldest)
    yield GaugeMetricFamily(
        "kybercore_queue_oldest_wait_seconds",
        "How long the oldest queued job has waited",
        value=waited,
    )
