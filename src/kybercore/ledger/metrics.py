"""``/metrics`` in Prometheus' text format, from what KyberCore already holds in memory.

A scrape reads the published printer views (the very ones ``GET /api/printers`` answers
with), the ledger's job counts and queue figures (kept up to date as they are written and
polled), and a few counters: it never asks a printer or the database anything.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

if TYPE_CHECKING:
    from kybercore.ledger.service import LedgerService

HEATERS = ("extruder", "bed")
"""The heaters of a printer view (``bed`` is Klipper's ``heater_bed``)."""


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


class FleetCollector(Collector):
    """Builds every KyberCore metric at scrape time from the ledger's in-memory state."""

    def __init__(self, ledger: LedgerService) -> None:
        self._ledger = ledger

    def collect(self) -> Iterator[Metric]:
        """The metrics, as of now."""
        ledger = self._ledger
        views = ledger.fleet.views()
        yield from _printer_metrics(views)
        states = GaugeMetricFamily(
            "kybercore_printer_state",
            "1 for the printer's state in the ledger's timeline",
            labels=["printer", "state"],
        )
        for printer, state in sorted(ledger.timeline.current.items()):
            states.add_metric([printer, state], 1)
        yield states
        jobs = CounterMetricFamily(
            "kybercore_jobs",
            "Printed jobs in the ledger, by printer and Moonraker outcome",
            labels=["printer", "outcome"],
        )
        for (printer, outcome), count in sorted(ledger.job_counts.items()):
            jobs.add_metric([printer, outcome], count)
        yield jobs
        yield from _queue_metrics(ledger.queue)
        reconnects = CounterMetricFamily(
            "kybercore_moonraker_reconnects",
            "Times a printer's Moonraker session came back online after being online",
            labels=["printer"],
        )
        for printer, count in sorted(ledger.reconnects.items()):
            reconnects.add_metric([printer], count)
        yield reconnects
        yield GaugeMetricFamily(
            "kybercore_browser_clients",
            "Browser WebSockets connected to /ws",
            value=ledger.fleet.hub.client_count,
        )
        yield GaugeMetricFamily(
            "kybercore_event_loop_lag_seconds",
            "How late the event loop last ran a timer (0.5 s period)",
            value=ledger.loop_lag,
        )


def _printer_metrics(views: list[dict[str, Any]]) -> Iterator[Metric]:
    counts = Counter((str(v["connection"]), str(v["klippy_state"])) for v in views)
    printers = GaugeMetricFamily(
        "kybercore_printers",
        "Printers by connection and Klippy state",
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
