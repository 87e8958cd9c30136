"""Uploading through a front (KyberCore on NATS): the file crosses the broker's object store
to the printer's owner, which uploads it to the printer's real Moonraker (and starts it) as
``kybercore serve`` does. Real processes: nats-server, two workers, a front, and the real
virtual printers. Nothing is left in the object store."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_until
from tests.scale.cluster import Cluster, fresh_cluster
from tests.scale.objects import objects_left

pytestmark = pytest.mark.integration

PRINTS_WITHIN = 30.0
"""An upload's start reaches print_stats "printing" (about a second on an idle machine)."""
MB = 1024 * 1024


@pytest.fixture
def cluster(fleet_stacks: list[PrinterStack], tmp_path: Path) -> Iterator[Cluster]:
    with fresh_cluster(fleet_stacks, tmp_path) as started:
        yield started


def stack_of(stacks: list[PrinterStack], printer_id: str) -> PrinterStack:
    return next(s for s in stacks if s.options.name == printer_id)


def large_gcode(size: int) -> bytes:
    """A valid slicer-style file of about ``size`` bytes: travel moves and comments."""
    head, *rest = travel_gcode(moves=4).decode().splitlines(keepends=True)
    filler, total, i = [], 0, 0
    while total < size:
        line = f"G1 X{50 + i % 50} Y{50 + i % 40} F6000 ; padding {i:09d} {uuid.uuid4().hex}\n"
        filler.append(line)
        total += len(line)
        i += 1
    body = rest[:3] + filler + rest[3:]  # after G90, G28, G1 Z5
    return (head + "".join(body)).encode()


def on_moonraker(stack: PrinterStack, name: str) -> bytes | None:
    """The file as the printer's own Moonraker has it, or None when it is not listed."""
    listed = httpx.get(f"{stack.url}/server/files/list", params={"root": "gcodes"}, timeout=10)
    if name not in [f["path"] for f in listed.json()["result"]]:
        return None
    return httpx.get(f"{stack.url}/server/files/gcodes/{name}", timeout=30).content


def print_stats(stack: PrinterStack) -> dict[str, Any]:
    answer = httpx.get(f"{stack.url}/printer/objects/query", params={"print_stats": ""}, timeout=10)
    stats: dict[str, Any] = answer.json()["result"]["status"]["print_stats"]
    return stats


def job_state(cluster: Cluster, printer_id: str) -> str:
    view = httpx.get(f"{cluster.front.url}/api/printers/{printer_id}", timeout=10).json()
    return str(view["job"]["state"])


def upload(cluster: Cluster, printer_id: str, name: str, data: bytes, **form: str) -> Any:
    answer = httpx.post(
        f"{cluster.front.url}/api/printers/{printer_id}/files",
        files={"file": (name, data)},
        data=form,
        timeout=120,
    )
    assert answer.status_code == 201, answer.text
    return answer.json()


def test_a_file_larger_than_a_nats_message_lands_on_the_printer(
    cluster: Cluster, fleet_stacks: list[PrinterStack]
) -> None:
    stack = stack_of(fleet_stacks, "fleet-b")
    name = f"large-{uuid.uuid4().hex[:6]}.gcode"
    data = large_gcode(3 * MB)  # NATS refuses messages over 1 MB
    try:
        body = upload(cluster, "fleet-b", name, data)
        assert (body["action"], body["ok"], body["uploaded"], body["started"]) == (
            "upload",
            True,
            True,
            None,
        )
        assert on_moonraker(stack, name) == data
        files = httpx.get(f"{cluster.front.url}/api/printers/fleet-b/files", timeout=30).json()
        assert name in [f["path"] for f in files]
        objects, size = objects_left(cluster.broker.url)
        assert objects == []
        assert size < 4096  # the 3 MB of chunks purged, not only marked deleted
    finally:
        httpx.delete(
            f"{cluster.front.url}/api/printers/fleet-b/files", params={"path": name}, timeout=30
        )


def test_an_upload_with_start_prints_it_on_the_printer(
    cluster: Cluster, fleet_stacks: list[PrinterStack]
) -> None:
    stack = stack_of(fleet_stacks, "fleet-a")
    url = cluster.front.url
    wait_until(
        lambda: job_state(cluster, "fleet-a") not in ("printing", "paused"), 30, "fleet-a idle"
    )
    name = f"started-{uuid.uuid4().hex[:6]}.gcode"
    data = travel_gcode()
    try:
        body = upload(cluster, "fleet-a", name, data, start="true")
        assert (body["uploaded"], body["started"], body["start"]["ok"]) == (True, True, True)
        assert "Uploaded" in body["message"]
        printing = {"state": "printing", "filename": name}
        wait_until(
            lambda: printing.items() <= print_stats(stack).items(),
            PRINTS_WITHIN,
            "the printer printing the file",
        )
        shown = lambda: job_state(cluster, "fleet-a") == "printing"  # noqa: E731
        wait_until(shown, 15, "the front showing it printing")
        assert on_moonraker(stack, name) == data
        assert objects_left(cluster.broker.url)[0] == []
    finally:
        # Leave the shared printer idle: cancelled, then the job forgotten.
        httpx.post(f"{url}/api/printers/fleet-a/actions/cancel", json={}, timeout=30)
        wait_until(
            lambda: print_stats(stack)["state"] not in ("printing", "paused"),
            30,
            "fleet-a no longer printing",
        )
        reset = httpx.post(
            f"{url}/api/printers/fleet-a/gcode", json={"script": "SDCARD_RESET_FILE"}, timeout=30
        )
        assert reset.status_code == 200, reset.text
        httpx.delete(f"{url}/api/printers/fleet-a/files", params={"path": name}, timeout=30)
