"""KyberCore on NATS as real processes: a nats-server, ingest workers and a front over
real virtual printers. The failure table of the design, end to end: a worker killed, a
worker joining, a worker paused past its lease, the broker restarted."""

from __future__ import annotations

import signal
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.scale.broker import LocalServer
from kybercore.scale.slots import slot_of
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_until
from tests.scale.cluster import (
    SETTLE,
    SLOTS,
    TTL,
    Cluster,
    moonraker_sockets,
    two_workers_and_a_front,
)
from tests.scale.replay import no_overlap

# A dead worker's printers are fresh again within TTL + TTL/3 + a Moonraker connect; the
# issue's promise is 10 s at TTL 3. Not slackened: it is the product's promise.
FRESH_AGAIN = 10.0
AT_ONCE = 2.5
"""An answer "at once": no timeout involved (5× a busy machine's half second)."""


@pytest.fixture
def cluster(
    fleet_stacks: list[PrinterStack], nats_server: LocalServer, tmp_path: Path
) -> Iterator[Cluster]:
    with two_workers_and_a_front(fleet_stacks, nats_server, tmp_path) as started:
        yield started


def owner(cluster: Cluster, printer_id: str) -> str:
    """The worker owning the printer now, from the own/drop logs."""
    slot = slot_of(printer_id, SLOTS)
    owners = [name for name, w in cluster.workers.items() if slot in w.owned()]
    assert len(owners) <= 1, owners
    return owners[0] if owners else ""


def respond(cluster: Cluster, printer_id: str, sent: dict[str, int]) -> httpx.Response:
    """Send a uniquely marked RESPOND; remember the marker with the answer's status."""
    marker = f"kc-{uuid.uuid4().hex[:10]}"
    answer = httpx.post(
        f"{cluster.front.url}/api/printers/{printer_id}/gcode",
        json={"script": f"RESPOND MSG={marker}"},
        timeout=30,
    )
    sent[marker] = answer.status_code
    return answer


def console_markers(stack: PrinterStack) -> list[str]:
    """The RESPOND markers Moonraker's gcode store holds as commands run."""
    store = httpx.get(f"{stack.url}/server/gcode_store", params={"count": 1000}, timeout=10)
    return [
        e["message"].removeprefix("RESPOND MSG=")
        for e in store.json()["result"]["gcode_store"]
        if e["type"] == "command" and e["message"].startswith("RESPOND MSG=kc-")
    ]


def test_failover_rebalance_fencing_and_broker_restart(
    cluster: Cluster, fleet_stacks: list[PrinterStack], tmp_path: Path
) -> None:
    count = len(fleet_stacks)
    workers = cluster.workers
    w1, w2 = workers["w1"], workers["w2"]
    sent: dict[str, int] = {}
    took = wait_until(lambda: len(w1.owned()) == len(w2.owned()) == 8, SETTLE, "an even split")
    wait_until(lambda: cluster.all_fresh(count), 60, "every printer fresh through the front")
    print(f"8/8 split in {took:.1f} s")
    assert respond(cluster, "fleet-a", sent).status_code == 200

    # 1. kill -9 the owner of fleet-a: a command answers 503 at once, then all fresh.
    assert owner(cluster, "fleet-a") == "w1"
    killed_at, died = time.monotonic(), {"w1": time.time()}
    w1.signal(signal.SIGKILL)
    w1.proc.wait()
    began = time.monotonic()
    answer = respond(cluster, "fleet-a", sent)
    assert answer.status_code == 503, answer.text
    assert answer.json()["error"]["code"] == "owner_moving"
    assert time.monotonic() - began < AT_ONCE
    wait_until(lambda: not cluster.all_fresh(count), SETTLE, "fleet-a stale or moved")
    wait_until(lambda: cluster.all_fresh(count), FRESH_AGAIN, "every printer fresh again")
    fresh_in = time.monotonic() - killed_at
    print(f"fresh again {fresh_in:.1f} s after kill -9 (TTL {TTL:g} s)")
    assert fresh_in <= FRESH_AGAIN
    assert respond(cluster, "fleet-a", sent).status_code == 200

    # 2. A third worker joins: the two share the slots.
    w3 = cluster.worker("w3")
    took = wait_until(lambda: len(w2.owned()) == len(w3.owned()) == 8, SETTLE, "w2 and w3 at 8/8")
    print(f"rebalanced in {took:.1f} s")
    wait_until(lambda: cluster.all_fresh(count), SETTLE, "every printer fresh after the rebalance")

    # 3. Pause fleet-a's owner past its lease: the other takes over; the paused one,
    #    continued, fences itself and runs none of the commands sent meanwhile.
    paused = workers[owner(cluster, "fleet-a")]
    other = w3 if paused is w2 else w2
    paused.signal(signal.SIGSTOP)
    try:
        answer = respond(cluster, "fleet-a", sent)
        # Its subscriptions still exist: no acknowledgement, so the outcome is unknown.
        assert answer.status_code in (503, 504), answer.text
        wait_until(lambda: len(other.owned()) == SLOTS, SETTLE, "the other worker owns every slot")
    finally:
        paused.signal(signal.SIGCONT)
    wait_until(lambda: cluster.all_fresh(count), SETTLE, "every printer fresh after the takeover")
    wait_until(lambda: not paused.owned(), SETTLE, "the paused worker dropped its slots")
    assert respond(cluster, "fleet-a", sent).status_code == 200

    # 4. The broker restarts: every process reconnects, every printer fresh again.
    cluster.broker.stop()
    # Meanwhile the front says why its printers are stale: it is cut off, not they.
    wait_until(
        lambda: all(
            v["connection"] == "stale" and "lost its connection to the NATS broker" in
            v["connection_error"] for v in cluster.views()
        ),
        SETTLE, "the front to say it is cut off",
    )  # fmt: skip
    cluster.broker.start(port=cluster.broker.port)
    wait_until(lambda: cluster.all_fresh(count), 60, "every printer fresh after the broker restart")
    # JetStream recovers its streams for a few seconds after a restart: leases may still
    # move, and a command meanwhile is refused with "owner moving, retry" (never run).
    wait_until(
        lambda: respond(cluster, "fleet-a", sent).status_code == 200, SETTLE, "a command runs again"
    )

    # Every command answered 200 ran exactly once; none ran twice.
    ran = console_markers(next(s for s in fleet_stacks if s.options.name == "fleet-a"))
    for marker, status in sent.items():
        assert ran.count(marker) == (1 if status == 200 else ran.count(marker)) <= 1, marker
    no_overlap([w.leases_log for w in workers.values()], died)


def test_the_front_reads_acts_and_edits_through_the_workers(cluster: Cluster) -> None:
    wait_until(lambda: cluster.all_fresh(3), 60, "every printer fresh")
    url = cluster.front.url
    answer = httpx.post(f"{url}/api/printers/fleet-b/gcode", json={"script": "M115"}, timeout=30)
    assert answer.status_code == 200, answer.text
    assert any("FIRMWARE_NAME" in line for line in answer.json()["response"])
    check = httpx.post(f"{url}/api/printers/fleet-c/actions/pause/check", json={}, timeout=30)
    assert check.status_code == 200, check.text
    assert check.json()["level"] == "block"  # nothing to pause: judged on the owner's state
    assert httpx.get(f"{url}/api/printers/nope", timeout=10).status_code == 404
    files = httpx.get(f"{url}/api/printers/fleet-a/files", timeout=30)
    assert files.status_code == 200, files.text
    # The M115 above and its answer are among the printer's latest console entries (in a
    # full run, other tests' prints may write there too).
    history = httpx.get(f"{url}/api/printers/fleet-b/console", params={"count": 50}, timeout=30)
    assert history.status_code == 200
    messages = [entry["message"] for entry in history.json()]
    assert "M115" in messages
    assert any("FIRMWARE_NAME" in m for m in messages[messages.index("M115") :])
    last = httpx.get(f"{url}/api/printers/fleet-b/console", params={"count": 1}, timeout=30)
    assert len(last.json()) == 1
    # Edits land in the registry bucket and the workers follow them.
    renamed = httpx.patch(f"{url}/api/printers/fleet-b", json={"name": "Renamed B"}, timeout=30)
    assert renamed.status_code == 200, renamed.text
    wait_until(
        lambda: _name(cluster, "fleet-b") == "Renamed B",
        SETTLE,
        "the owner's view shows the new name",
    )
    # The queue and the notifications are served (tests/scale/test_front_queue.py,
    # tests/scale/test_front_notify.py).
    assert httpx.get(f"{url}/api/queue", timeout=10).status_code == 200
    channels = httpx.get(f"{url}/api/notifications/channels", timeout=10)
    assert channels.status_code == 200, channels.text
    assert channels.json() == []


def _name(cluster: Cluster, printer_id: str) -> str:
    view: Callable[[], list[dict[str, str]]] = cluster.views
    return next(v["name"] for v in view() if v["id"] == printer_id)


def test_a_printer_moved_to_a_site_is_held_by_that_sites_worker_only(
    cluster: Cluster, fleet_stacks: list[PrinterStack]
) -> None:
    wait_until(lambda: cluster.all_fresh(3), 60, "every printer fresh")
    url = cluster.front.url
    stack_c = fleet_stacks[2]
    # The suite's other KyberCore processes may hold sockets to it too: count the change.
    held = moonraker_sockets(stack_c)
    moved = httpx.patch(f"{url}/api/printers/fleet-c", json={"site": "lab-b"}, timeout=30)
    assert moved.status_code == 200, moved.text
    # No worker of lab-b yet: the default site's owner lets it go, and the front says
    # which worker to start.
    wait_until(
        lambda: "--site lab-b" in _view(cluster, "fleet-c")["connection_error"],
        SETTLE,
        "fleet-c waiting for a lab-b worker",
    )
    assert _view(cluster, "fleet-c")["connection"] == "connecting"
    closed = "the cluster's session closed"
    wait_until(lambda: moonraker_sockets(stack_c) == held - 1, SETTLE, closed)
    gcode = {"script": "M115"}
    no_owner = httpx.post(f"{url}/api/printers/fleet-c/gcode", json=gcode, timeout=30)
    assert no_owner.status_code == 503, no_owner.text
    # A lab-b worker holds every lab-b slot, and fleet-c through it; the default site's
    # two still split theirs.
    b1 = cluster.worker("b1", "--site", "lab-b")
    wait_until(lambda: cluster.all_fresh(3), 60, "fleet-c fresh through b1")
    assert _view(cluster, "fleet-c")["site"] == "lab-b"
    assert len(b1.owned()) == SLOTS
    assert len(cluster.workers["w1"].owned()) == len(cluster.workers["w2"].owned()) == SLOTS // 2
    assert moonraker_sockets(stack_c) == held  # connected once again, from its site
    answer = httpx.post(f"{url}/api/printers/fleet-c/gcode", json=gcode, timeout=30)
    assert answer.status_code == 200, answer.text
    assert any("FIRMWARE_NAME" in line for line in answer.json()["response"])


def _view(cluster: Cluster, printer_id: str) -> dict[str, Any]:
    return next(v for v in cluster.views() if v["id"] == printer_id)
