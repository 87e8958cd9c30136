"""The job queue on NATS: a job added on a front is dispatched by the front holding the
dispatcher role, printed by the worker that owns the printer, followed to its end, and the
next copy waits for the plate to be cleared, exactly as with ``kybercore serve``. Real
nats-server, workers, front, PostgreSQL, Moonraker and Klippy."""

from __future__ import annotations

from typing import Any

import httpx

from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_until
from tests.scale.cluster import Cluster

SHORT = travel_gcode(moves=4, feedrate=6000)
"""Homing plus 2 s of moves, no heating."""
PRINT_WITHIN = 120.0
"""Dispatch, upload and a ~5 s print on an idle machine; 5× slack and more."""


def call(cluster: Cluster, method: str, path: str, **options: Any) -> Any:
    answer = httpx.request(method, f"{cluster.front.url}{path}", timeout=60, **options)
    assert answer.status_code in (200, 201), answer.text
    return answer.json()


def gate(cluster: Cluster, printer: str) -> str:
    gates = call(cluster, "GET", "/api/gates")
    state: str = gates.get(printer, {"state": "available"})["state"]
    return state


def test_a_job_added_on_a_front_prints_on_a_workers_printer_one_cleared_plate_at_a_time(
    shared_cluster: Cluster, fleet_stacks: list[PrinterStack]
) -> None:
    cluster = shared_cluster
    printer = fleet_stacks[1].options.name
    created = call(
        cluster, "POST", "/api/jobs",
        files={"file": ("on-nats.gcode", SHORT)}, data={"quantity": "2", "printer": printer},
    )  # fmt: skip
    job_id = created["id"]

    wait_until(lambda: gate(cluster, printer) == "awaiting_clear", PRINT_WITHIN, "copy 1 ended")
    tried = call(cluster, "GET", f"/api/jobs/{job_id}/attempts")
    assert [(a["copy"], a["printer"], a["state"]) for a in tried] == [(1, printer, "completed")]
    # The front hears no Moonraker notifications: the tracker found the job by its name.
    assert tried[0]["moonraker_job_id"]
    job = call(cluster, "GET", f"/api/jobs/{job_id}")
    assert (job["done"], job["in_flight"], job["left"]) == (0, 1, 1)
    # The printer really printed it, under the attempt's own name.
    stats = httpx.get(f"{fleet_stacks[1].url}/printer/objects/query?print_stats", timeout=10)
    shown = stats.json()["result"]["status"]["print_stats"]
    assert (shown["filename"], shown["state"]) == (tried[0]["upload_name"], "complete")

    # Copy 2 waits for the plate: it starts only after the clear.
    assert len(call(cluster, "GET", f"/api/jobs/{job_id}/attempts")) == 1
    call(cluster, "POST", f"/api/printers/{printer}/clear", json={"verdict": "good"})
    wait_until(
        lambda: len(call(cluster, "GET", f"/api/jobs/{job_id}/attempts")) == 2,
        PRINT_WITHIN, "copy 2 dispatched after the clear",
    )  # fmt: skip
    wait_until(lambda: gate(cluster, printer) == "awaiting_clear", PRINT_WITHIN, "copy 2 ended")
    call(cluster, "POST", f"/api/printers/{printer}/clear", json={"verdict": "good"})
    job = call(cluster, "GET", f"/api/jobs/{job_id}")
    assert (job["done"], job["state"]) == (2, "done"), job
