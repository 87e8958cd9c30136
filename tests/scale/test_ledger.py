"""The ledger on NATS: each ingest worker writes the job history and state timeline of the
printers it holds into the database every front reads (a real PostgreSQL, started by the
fixtures), so a front answers /api/history and /api/stats as ``serve`` does."""

from __future__ import annotations

from typing import Any

import httpx

from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_until
from tests.scale.cluster import Cluster

SHORT = travel_gcode(moves=4, feedrate=6000)
"""Homing plus 2 s of moves, no heating."""
PRINT_WITHIN = 120.0
"""A short print ends in ~5 s on an idle machine."""


def front_get(cluster: Cluster, path: str, **params: Any) -> Any:
    answer = httpx.get(f"{cluster.front.url}{path}", params=params, timeout=30)
    assert answer.status_code == 200, answer.text
    return answer.json()


def test_a_print_through_a_front_reaches_its_history_and_statistics(
    shared_cluster: Cluster, fleet_stacks: list[PrinterStack]
) -> None:
    cluster = shared_cluster
    stack = fleet_stacks[1]
    printer = stack.options.name
    upload = httpx.post(
        f"{stack.url}/server/files/upload", files={"file": ("nats-ledger.gcode", SHORT)}, timeout=30
    )
    assert upload.status_code == 201, upload.text
    url = f"{cluster.front.url}/api/printers/{printer}/actions/start"
    started = httpx.post(url, json={"filename": "nats-ledger.gcode"}, timeout=60)
    assert started.status_code == 200, started.text

    def recorded() -> bool:
        page = front_get(cluster, "/api/history", printer=printer, file="nats-ledger")
        return any(row["status"] == "completed" for row in page["items"])

    wait_until(recorded, PRINT_WITHIN, "the finished print in the front's history")
    # One row per job, however often the worker's catch-ups read it.
    page = front_get(cluster, "/api/history", printer=printer, file="nats-ledger")
    assert page["total"] == 1, page
    # The state timeline, written by the same worker, saw it print.
    rows = front_get(cluster, "/api/stats", group_by="printer")["rows"]
    mine = next(row for row in rows if row["key"] == printer)
    assert mine["jobs"].get("completed", 0) >= 1
    assert mine["utilisation"] is not None, mine
    assert mine["utilisation"] > 0, mine
