"""The job queue on NATS: a job added on a front is dispatched by the front holding the
dispatcher role, printed by the worker that owns the printer, followed to its end, and the
next copy waits for the plate to be cleared, exactly as with ``kybercore serve``. Real
nats-server, workers, front, PostgreSQL, Moonraker and Klippy."""

from __future__ import annotations

import asyncio
import hashlib
import os
import signal
from collections.abc import Callable
from typing import Any
from uuid import uuid4

import httpx

from kybercore.sim.stack import PrinterStack
from tests.browser_mirror import BrowserMirror
from tests.helpers import KyberCoreServer, travel_gcode, wait_until
from tests.scale.cluster import TTL, Cluster

SHORT = travel_gcode(moves=4, feedrate=6000)
"""Homing plus 2 s of moves, no heating."""
PRINT_WITHIN = 120.0
"""Dispatch, upload and a ~5 s print on an idle machine; 5× slack and more."""


TAKEOVER = 5 * (TTL + TTL / 3)
"""The dispatcher role moves ~TTL + TTL/3 after its holder died; 5× slack."""


def call(cluster: Cluster | KyberCoreServer, method: str, path: str, **options: Any) -> Any:
    front = cluster.front if isinstance(cluster, Cluster) else cluster
    answer = httpx.request(method, f"{front.url}{path}", timeout=60, **options)
    assert answer.status_code in (200, 201), answer.text
    return answer.json()


def gate(cluster: Cluster | KyberCoreServer, printer: str) -> str:
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


def test_a_file_already_on_a_printer_is_queued_through_a_front(
    shared_cluster: Cluster, fleet_stacks: list[PrinterStack]
) -> None:
    cluster = shared_cluster
    stack = fleet_stacks[2]
    printer = stack.options.name
    name = f"on-printer-{uuid4().hex[:8]}.gcode"
    # Over a NATS message's 1 MB: it can only cross in the broker's object store.
    original = SHORT + b"".join(b"; padding %07d\n" % i for i in range(80_000))
    upload = {"file": (name, original)}
    httpx.post(f"{stack.url}/server/files/upload", files=upload, timeout=60).raise_for_status()
    try:
        call(cluster, "POST", "/api/queue", json={"paused": True})  # the file is what is tested
        created = call(
            cluster, "POST", "/api/jobs", json={"printer": printer, "path": name, "pin": True}
        )
        file = created["file"]
        assert (file["name"], file["size"]) == (name, len(original))
        assert file["sha256"] == hashlib.sha256(original).hexdigest()
        assert created["requirements"]["printer"] == printer

        missing = httpx.post(
            f"{cluster.front.url}/api/jobs", json={"printer": printer, "path": "nope.gcode"},
            timeout=60,
        )  # fmt: skip
        # As on `kybercore serve`: the printer's Moonraker's own answer.
        assert missing.status_code == 404, missing.text
        error = missing.json()["error"]
        assert error["code"] == "not_found"
        assert error["message"].startswith(f"{printer}: Moonraker refused the request (404)")
    finally:
        httpx.delete(f"{stack.url}/server/files/gcodes/{name}", timeout=30).raise_for_status()


async def queue_frames_while(
    ws_url: str, act: Callable[[], Any], until: Callable[[list[dict[str, Any]]], bool]
) -> list[dict[str, Any]]:
    """A browser on ``ws_url``: the queue frames it gets while ``act`` runs, until ``until``."""
    async with BrowserMirror(ws_url) as browser:
        await asyncio.to_thread(act)
        await browser.wait(lambda: until(browser.events("queue")), 60, "the queue's frames")
        return browser.events("queue")


def test_fronts_share_the_queue_and_another_dispatches_when_the_first_dies(
    shared_cluster: Cluster, fleet_stacks: list[PrinterStack], front_b: KyberCoreServer
) -> None:
    cluster, other = shared_cluster, front_b
    printer = fleet_stacks[0].options.name
    # Front A (first up) dispatches; a browser on front B sees every change it makes.
    added: dict[str, Any] = {}

    def add() -> None:
        upload = {"file": ("shared.gcode", SHORT)}
        fields = {"quantity": "2", "printer": printer}
        added.update(call(cluster, "POST", "/api/jobs", files=upload, data=fields))

    def copy_ended(frames: list[dict[str, Any]]) -> bool:
        return any(
            f["kind"] == "attempt"
            and f["event"] == "attempt_completed"
            and f["attempt"]["job_id"] == added["id"]
            for f in frames
        )

    frames = asyncio.run(queue_frames_while(other.ws_url, add, copy_ended))
    assert any(f.get("event") == "attempt_reserved" for f in frames), frames
    job_id = added["id"]

    # Front A dies without a word. Front B takes the role and dispatches copy 2, from
    # the file front A stored (B has it from the broker, not from a disk).
    wait_until(lambda: gate(other, printer) == "awaiting_clear", PRINT_WITHIN, "copy 1")
    assert "took the dispatcher role" in cluster.front.log.read_text()
    assert "took the dispatcher role" not in other.log.read_text()
    sha256 = added["file"]["sha256"]
    on_disk_b = other.printers_file.with_name("files") / f"{sha256}.gcode"
    assert not on_disk_b.exists()
    os.kill(cluster.front.pid, signal.SIGKILL)
    call(other, "POST", f"/api/printers/{printer}/clear", json={"verdict": "good"})
    wait_until(
        lambda: len(call(other, "GET", f"/api/jobs/{job_id}/attempts")) == 2,
        TAKEOVER, "copy 2 dispatched by front B",
    )  # fmt: skip
    wait_until(lambda: gate(other, printer) == "awaiting_clear", PRINT_WITHIN, "copy 2")
    tried = call(other, "GET", f"/api/jobs/{job_id}/attempts")
    assert [(a["copy"], a["state"]) for a in tried] == [(1, "completed"), (2, "completed")]
    assert on_disk_b.exists()
