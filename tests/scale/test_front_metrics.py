"""``/metrics`` on a front: the printers it follows from the workers, counted by state
with their heaters, the queue and the jobs from the shared database, a printer no worker
reports counted as stale, and whether the front is connected to the broker. Real
nats-server, workers, front, PostgreSQL, Moonraker and Klippy."""

from __future__ import annotations

import signal
from pathlib import Path

import httpx
import pytest

from kybercore.registry.store import write_printers
from kybercore.scale.broker import LocalServer
from kybercore.sim.stack import PrinterStack, free_port
from tests.browser_mirror import BrowserMirror
from tests.helpers import KyberCoreServer, wait_for, wait_until
from tests.metrics_scrape import (
    Samples,
    assert_printers_as_viewed,
    by_state,
    jobs_as_in_stats,
    parse,
    same_instant,
)
from tests.scale.cluster import SLOTS, Cluster
from tests.scale.test_front_queue import PRINT_WITHIN, SHORT

pytestmark = pytest.mark.integration

READ_WITHIN = 60.0
"""The front reads the job counts every 10 s and the queue every 2 s: 3× slack and more."""
STALE_WITHIN = 30.0
"""A silent slot is stale after 2 s (checked every 0.25 s): 10× slack and more."""


async def scrape(api: httpx.AsyncClient) -> dict[str, dict[tuple[tuple[str, str], ...], float]]:
    answer = await api.get("/metrics")
    assert answer.status_code == 200, answer.text
    return parse(answer.text)


def worker_slots(samples: Samples) -> tuple[set[str], float]:
    """The workers ``kybercore_worker_slots`` names, and the slots they report in all."""
    slots = {dict(labels)["worker"]: n for labels, n in samples["kybercore_worker_slots"].items()}
    return set(slots), sum(slots.values())


# A cluster to start, a print, then the front's next reads: more than the default 120 s may
# pass on a busy machine (its waits alone allow PRINT_WITHIN + 2 * READ_WITHIN).
@pytest.mark.timeout(600)
async def test_a_fronts_metrics_count_its_printers_and_read_the_postgres_database(
    shared_cluster: Cluster, fleet_stacks: list[PrinterStack]
) -> None:
    cluster = shared_cluster
    printer = fleet_stacks[1].options.name
    async with httpx.AsyncClient(base_url=cluster.front.url, timeout=60) as api:
        # A job of two copies: copy 1 prints on a worker's printer, whose plate then waits
        # to be cleared, and copy 2 waits in the queue.
        created = await api.post(
            "/api/jobs",
            files={"file": ("front-metrics.gcode", SHORT)},
            data={"quantity": "2", "printer": printer},
        )
        assert created.status_code == 201, created.text

        # The printer's earlier prints (other tests') are in the ledger too: copy 1 is found
        # by its name, and the job counts are compared with the ledger's statistics below.
        seen: dict[str, object] = {}

        async def copy_1_recorded() -> bool:
            samples = await scrape(api)
            history = await api.get(
                "/api/history",
                params={"printer": printer, "file": "front-metrics", "status": "completed"},
            )
            seen.update(
                state={
                    dict(labels)["state"]
                    for labels, value in samples["kybercore_printer_state"].items()
                    if value == 1 and dict(labels)["printer"] == printer
                },
                jobs=samples["kybercore_queue_jobs"][()],
                left=samples["kybercore_queue_copies_left"][()],
                recorded=history.json()["total"],
            )
            return seen == {"state": {"awaiting_clear"}, "jobs": 1, "left": 1, "recorded": 1}

        try:
            await wait_for(copy_1_recorded, PRINT_WITHIN + READ_WITHIN, "copy 1 in the metrics")
        except AssertionError as failed:
            raise AssertionError(f"{failed}; the metrics and the ledger showed {seen}") from None
        await wait_for(lambda: jobs_as_in_stats(api), READ_WITHIN, "jobs as in /api/stats")
        shared = (set(cluster.workers), SLOTS)

        async def every_worker_holds_slots() -> bool:
            return worker_slots(await scrape(api)) == shared

        await wait_for(every_worker_holds_slots, STALE_WITHIN, "every worker's share reported")

        async with BrowserMirror(cluster.front.ws_url):
            views, samples = await same_instant(api)
            health = (await api.get("/api/health")).json()
    assert by_state(samples) == {"online/ready": len(fleet_stacks)}
    assert_printers_as_viewed(views, samples)
    states = {
        dict(labels)["printer"]: dict(labels)["state"]
        for labels, value in samples["kybercore_printer_state"].items()
        if value == 1
    }
    assert states == {
        s.options.name: "awaiting_clear" if s.options.name == printer else "idle"
        for s in fleet_stacks
    }
    assert samples["kybercore_browser_clients"][()] == health["browsers"] >= 1
    assert samples["kybercore_event_loop_lag_seconds"][()] >= 0
    # Each worker, by the slots it reports and how late its loop runs.
    assert worker_slots(samples) == shared, samples.get("kybercore_worker_slots")
    lags = samples["kybercore_worker_event_loop_lag_seconds"]
    assert {dict(labels)["worker"] for labels in lags} == set(cluster.workers)
    assert all(0 <= lag < 60 for lag in lags.values()), lags
    # Counted by the workers holding the sessions: a front leaves them out.
    assert "kybercore_moonraker_reconnects_total" not in samples


async def test_a_printer_no_worker_reports_is_stale_in_a_fronts_metrics(
    shared_cluster: Cluster, fleet_stacks: list[PrinterStack]
) -> None:
    cluster = shared_cluster
    names = {s.options.name for s in fleet_stacks}
    async with httpx.AsyncClient(base_url=cluster.front.url, timeout=60) as api:

        async def all_ready() -> bool:
            # The suite's printers are shared: another test may have left one restarting.
            return by_state(await scrape(api)) == {"online/ready": len(fleet_stacks)}

        await wait_for(all_ready, STALE_WITHIN, "every printer online and ready")
        for worker in cluster.workers.values():
            worker.signal(signal.SIGKILL)

        async def all_stale() -> bool:
            # Every slot goes stale 2 s after its own last news, and the slots without these
            # printers may have been heard from last: no worker shown is waited for too.
            samples = await scrape(api)
            return (
                by_state(samples) == {"stale/ready": len(fleet_stacks)}
                and "kybercore_worker_slots" not in samples
            )

        await wait_for(all_stale, STALE_WITHIN, "every printer stale and no worker shown")
        samples = await scrape(api)
    states = samples["kybercore_printer_state"]
    assert states == {(("printer", name), ("state", "stale")): 1 for name in names}
    # The owners' last readings are not shown as the printers' now.
    for name in ("kybercore_heater_temperature_celsius", "kybercore_heater_target_celsius"):
        assert name not in samples, name
    assert "kybercore_print_progress_ratio" not in samples
    assert "kybercore_worker_slots" not in samples  # no worker reports anything
    assert "kybercore_worker_event_loop_lag_seconds" not in samples


def test_a_front_cut_off_from_the_broker_says_so_in_health_and_metrics(
    nats_server: LocalServer, tmp_path: Path
) -> None:
    # What a load balancer's health check or an alert reads: the printers are stale and
    # the actions refused because this front lost NATS, not because the printers did.
    write_printers(tmp_path / "printers.json", [])
    front = KyberCoreServer(
        tmp_path / "printers.json", free_port(), "--nats", nats_server.url, command="front"
    )
    front.start()
    try:

        def broker() -> tuple[object, ...]:
            """Health's broker, the metric, and /api/ready's status and error code."""
            health = httpx.get(f"{front.url}/api/health", timeout=10).json()["broker"]
            metrics = parse(httpx.get(f"{front.url}/metrics", timeout=10).text)
            ready = httpx.get(f"{front.url}/api/ready", timeout=10)
            code = ready.json().get("error", {}).get("code")
            return health, metrics["kybercore_broker_connected"][()], ready.status_code, code

        assert broker() == ("connected", 1, 200, None)
        nats_server.stop()
        cut_off = ("disconnected", 0, 503, "broker_unavailable")
        wait_until(lambda: broker() == cut_off, STALE_WITHIN, "the front to say so")
        nats_server.start(port=nats_server.port)
        back = ("connected", 1, 200, None)
        wait_until(lambda: broker() == back, STALE_WITHIN, "the front to reconnect")
    finally:
        front.stop()
