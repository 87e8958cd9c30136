"""The job queue over HTTP, end to end: a real ``kybercore serve`` over two real Moonraker +
Klippy printers (one with PLA loaded, one with PETG), driven through ``/api/jobs`` and
watched through ``/ws`` as a dashboard would."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.registry.models import Capabilities, PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.sim.stack import PrinterStack, free_port
from tests.browser_mirror import BrowserMirror
from tests.helpers import KyberCoreServer, travel_gcode, wait_for

pytestmark = pytest.mark.integration

PLA, PETG = "jobs-pla", "jobs-petg"
LIVE = ("pending", "uploading", "starting", "printing", "paused")
PRINT_WITHIN = 60.0
"""A copy queued -> printing on an idle printer: a dispatch round, an upload and a verified
start (a few seconds idle); the travel file then prints in about 5 s."""


def short_print() -> bytes:
    """A PLA travel-only file (no heating) that prints in a few seconds."""
    return travel_gcode(moves=6, feedrate=3600)


@pytest.fixture(scope="module")
def queue_server(
    start_stack: Callable[..., PrinterStack], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[KyberCoreServer]:
    """``kybercore serve`` with its own queue database over a PLA and a PETG printer."""
    stacks = {PLA: start_stack(PLA), PETG: start_stack(PETG)}
    folder: Path = tmp_path_factory.mktemp("jobs-api")
    write_printers(
        folder / "printers.json",
        [
            PrinterConfig(
                id=name,
                name=name.upper(),
                moonraker_url=stack.url,
                capabilities=Capabilities(material="PLA" if name == PLA else "PETG"),
            )
            for name, stack in stacks.items()
        ],
    )
    server = KyberCoreServer(folder / "printers.json", free_port(), "--heating-budget", "2")
    server.start()
    server.wait_online(2)
    yield server
    server.stop()


@pytest.fixture
async def api(queue_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=queue_server.url, timeout=60) as client:
        yield client
        # Leave the queue empty, running, and every plate clear for the next test.
        await client.post("/api/queue", json={"paused": False})
        for job in (await client.get("/api/jobs")).json():
            await client.delete(f"/api/jobs/{job['id']}", params={"confirm": "true"})
        await settle_gates(client)


async def settle_gates(api: httpx.AsyncClient) -> None:
    """Wait until no copy is on a printer, then clear or release every printer."""

    async def quiet() -> bool:
        jobs = (await api.get("/api/jobs", params={"finished": "true"})).json()
        tried = [a for j in jobs for a in await attempts(api, j["id"])]
        return not any(a["state"] in LIVE for a in tried)

    await wait_for(quiet, PRINT_WITHIN, "no copy on a printer")
    for printer, gate in (await api.get("/api/gates")).json().items():
        if gate["state"] == "awaiting_clear":
            await api.post(f"/api/printers/{printer}/clear", json={"verdict": "bad"})
        elif gate["state"] in ("held", "maintenance"):
            await api.post(f"/api/printers/{printer}/release")


@pytest.fixture
async def mirror(queue_server: KyberCoreServer) -> AsyncIterator[BrowserMirror]:
    async with BrowserMirror(queue_server.ws_url) as browser:
        yield browser


async def add_job(api: httpx.AsyncClient, name: str, **fields: Any) -> dict[str, Any]:
    """Upload ``short_print()`` as a job; its JSON."""
    data = {k: [str(x) for x in v] if isinstance(v, list) else str(v) for k, v in fields.items()}
    answer = await api.post("/api/jobs", files={"file": (name, short_print())}, data=data)
    assert answer.status_code == 201, answer.text
    job: dict[str, Any] = answer.json()
    return job


async def job(api: httpx.AsyncClient, job_id: int) -> dict[str, Any]:
    answer = await api.get(f"/api/jobs/{job_id}")
    assert answer.status_code == 200, answer.text
    body: dict[str, Any] = answer.json()
    return body


async def gate(api: httpx.AsyncClient, printer: str) -> str:
    gates = (await api.get("/api/gates")).json()
    state: str = gates.get(printer, {"state": "available"})["state"]
    return state


async def attempts(api: httpx.AsyncClient, job_id: int) -> list[dict[str, Any]]:
    answer = await api.get(f"/api/jobs/{job_id}/attempts")
    assert answer.status_code == 200, answer.text
    body: list[dict[str, Any]] = answer.json()
    return body


async def test_copies_run_one_at_a_time_on_the_printer_that_fits_each_after_a_clear(
    api: httpx.AsyncClient, mirror: BrowserMirror
) -> None:
    created = await add_job(api, "two-copies.gcode", quantity=2, material="pla")
    assert (created["quantity"], created["done"], created["state"]) == (2, 0, "queued")
    assert created["requirements"]["material"] == "pla"
    assert created["file"]["name"] == "two-copies.gcode"
    assert created["file"]["meta"]["filament_type"] == "PLA"
    job_id = created["id"]

    # The first copy prints on the PLA printer; its plate then waits for a clear.
    await wait_for(lambda: gate_is(api, PLA, "awaiting_clear"), PRINT_WITHIN, "first copy ended")
    first = await job(api, job_id)
    assert (first["done"], first["in_flight"], first["left"]) == (0, 1, 1)
    tried = await attempts(api, job_id)
    assert [(a["copy"], a["printer"], a["state"]) for a in tried] == [(1, PLA, "completed")]
    assert tried[0]["moonraker_job_id"]

    # Why the second copy waits: one line per printer, in both languages.
    why = (await api.get(f"/api/jobs/{job_id}/why")).json()
    subjects = {line["subject"]: line for line in why}
    assert {PLA, PETG} <= set(subjects), why
    assert all(line["en"] and line["es"] and line["code"] for line in why)

    # Good: the copy counts, and the next one starts on the same printer.
    cleared = await api.post(f"/api/printers/{PLA}/clear", json={"verdict": "good"})
    assert cleared.status_code == 200, cleared.text
    assert cleared.json()["state"] == "available"
    await wait_for(lambda: copies_tried(api, job_id, 2), PRINT_WITHIN, "second copy dispatched")
    await wait_for(lambda: gate_is(api, PLA, "awaiting_clear"), PRINT_WITHIN, "second copy ended")

    # Bad: the copy goes back to the queue and is printed again.
    bad = await api.post(f"/api/printers/{PLA}/clear", json={"verdict": "bad", "cause": "warped"})
    assert bad.status_code == 200, bad.text
    await wait_for(lambda: copies_tried(api, job_id, 3), PRINT_WITHIN, "bad copy printed again")
    await wait_for(lambda: gate_is(api, PLA, "awaiting_clear"), PRINT_WITHIN, "third print ended")
    await api.post(f"/api/printers/{PLA}/clear", json={"verdict": "good"})

    finished = await job(api, job_id)
    assert (finished["state"], finished["done"], finished["in_flight"]) == ("done", 2, 0)
    tried = await attempts(api, job_id)
    assert {a["printer"] for a in tried} == {PLA}
    assert [(a["verdict"], a["cause"]) for a in tried] == [
        ("good", ""),
        ("bad", "warped"),
        ("good", ""),
    ]
    assert await gate(api, PETG) == "available"
    # A finished job leaves the queue's list, and stays listed with ?finished=true.
    assert job_id not in [j["id"] for j in (await api.get("/api/jobs")).json()]
    listed = (await api.get("/api/jobs", params={"finished": "true"})).json()
    assert job_id in [j["id"] for j in listed]
    # Every change reached the dashboards on /ws.
    kinds = {frame.get("kind") for frame in mirror.events("queue")}
    assert {"job", "attempt", "gate"} <= kinds, kinds


async def gate_is(api: httpx.AsyncClient, printer: str, state: str) -> bool:
    return await gate(api, printer) == state


async def copies_tried(api: httpx.AsyncClient, job_id: int, count: int) -> bool:
    return len(await attempts(api, job_id)) >= count


async def test_a_job_no_printer_could_ever_print_is_refused_with_the_reasons(
    api: httpx.AsyncClient,
) -> None:
    # A 1 mm nozzle and a tag nobody has: refused at once, both reasons given.
    answer = await api.post(
        "/api/jobs",
        files={"file": ("wide.gcode", short_print())},
        data={"nozzle": "1.0", "tags": ["no-such-group"]},
    )
    assert answer.status_code == 422, answer.text
    error = answer.json()["error"]
    assert error["code"] == "never_printable"
    assert {r["code"] for r in error["reasons"]} == {"no_nozzle", "no_tags"}, error
    assert all(r["en"] and r["es"] and r["level"] == "block" for r in error["reasons"])
    assert "no-such-group" in error["message"]
    assert (await api.get("/api/jobs")).json() == []
    # A material nobody has loaded now is no reason to refuse: it can be loaded. It waits.
    waiting = await add_job(api, "abs.gcode", material="ABS")
    why = (await api.get(f"/api/jobs/{waiting['id']}/why")).json()
    assert {PLA, PETG} <= {line["subject"] for line in why}, why


async def test_cancelling_a_job_with_a_copy_printing_asks_first_then_stops_the_print(
    api: httpx.AsyncClient,
) -> None:
    created = await add_job(api, "long.gcode", printer=PLA, quantity=3)
    await wait_for(lambda: printing(api, created["id"]), PRINT_WITHIN, "a copy printing")

    asked = await api.delete(f"/api/jobs/{created['id']}")
    assert asked.status_code == 409, asked.text
    error = asked.json()["error"]
    assert error["code"] == "confirmation_required"
    assert PLA in " ".join(r["en"] for r in error["reasons"])
    assert (await job(api, created["id"]))["state"] == "queued"

    done = await api.delete(f"/api/jobs/{created['id']}", params={"confirm": "true"})
    assert done.status_code == 200, done.text
    assert done.json()["state"] == "cancelled"
    await wait_for(
        lambda: printer_idle(api, PLA), PRINT_WITHIN, "the print cancelled on the printer"
    )
    assert created["id"] not in [j["id"] for j in (await api.get("/api/jobs")).json()]


async def printing(api: httpx.AsyncClient, job_id: int) -> bool:
    return any(a["state"] == "printing" for a in await attempts(api, job_id))


async def printer_idle(api: httpx.AsyncClient, printer: str) -> bool:
    view = (await api.get(f"/api/printers/{printer}")).json()
    return view["job"]["state"] not in ("printing", "paused")


async def test_a_paused_queue_keeps_jobs_that_can_be_reordered_edited_and_resumed(
    api: httpx.AsyncClient,
) -> None:
    paused = await api.post("/api/queue", json={"paused": True})
    assert paused.status_code == 200, paused.text
    assert paused.json()["paused"] is True
    first = await add_job(api, "first.gcode", material="PLA")
    second = await add_job(api, "second.gcode", material="PLA", quantity=2)
    order = [j["id"] for j in (await api.get("/api/jobs")).json()]
    assert order == [first["id"], second["id"]]

    moved = await api.post(f"/api/jobs/{second['id']}/move", json={"before": first["id"]})
    assert moved.status_code == 200, moved.text
    assert [j["id"] for j in (await api.get("/api/jobs")).json()] == [second["id"], first["id"]]

    edited = await api.patch(f"/api/jobs/{first['id']}", json={"priority": 5, "quantity": 4})
    assert edited.status_code == 200, edited.text
    assert (edited.json()["priority"], edited.json()["quantity"]) == (5, 4)
    assert [j["id"] for j in (await api.get("/api/jobs")).json()] == [first["id"], second["id"]]

    state = (await api.get("/api/queue")).json()
    assert (state["paused"], state["queued"], state["copies_left"]) == (True, 2, 6)
    # Paused: nothing starts, and /why says so.
    why = (await api.get(f"/api/jobs/{first['id']}/why")).json()
    assert any(line["subject"] == "queue" for line in why), why
    assert await attempts(api, first["id"]) == []

    resumed = await api.post("/api/queue", json={"paused": False})
    assert resumed.json()["paused"] is False
    # The higher priority job goes first.
    await wait_for(lambda: copies_tried(api, first["id"], 1), PRINT_WITHIN, "dispatch resumed")
    assert await attempts(api, second["id"]) == []


async def test_a_held_printer_gets_nothing_until_released(api: httpx.AsyncClient) -> None:
    held = await api.post(f"/api/printers/{PLA}/hold", json={"reason": "nozzle change"})
    assert held.status_code == 200, held.text
    assert (held.json()["state"], held.json()["reason"]) == ("held", "nozzle change")
    created = await add_job(api, "held.gcode", material="PLA")
    why = (await api.get(f"/api/jobs/{created['id']}/why")).json()
    assert "nozzle change" in " ".join(line["en"] for line in why if line["subject"] == PLA)
    assert (await api.get("/api/queue")).json()["held"] == [PLA]

    released = await api.post(f"/api/printers/{PLA}/release")
    assert released.status_code == 200, released.text
    assert released.json()["state"] == "available"
    await wait_for(lambda: copies_tried(api, created["id"], 1), PRINT_WITHIN, "dispatch")


async def test_a_job_from_a_file_already_on_a_printer(api: httpx.AsyncClient) -> None:
    await api.post("/api/queue", json={"paused": True})
    stored = await api.post(
        f"/api/printers/{PLA}/files", files={"file": ("on-printer.gcode", short_print())}
    )
    assert stored.status_code == 201, stored.text
    answer = await api.post(
        "/api/jobs", json={"printer": PLA, "path": "on-printer.gcode", "pin": True, "quantity": 2}
    )
    assert answer.status_code == 201, answer.text
    body = answer.json()
    assert (body["file"]["name"], body["quantity"]) == ("on-printer.gcode", 2)
    assert body["requirements"]["printer"] == PLA
    assert body["file"]["size"] == len(short_print())
    missing = await api.post("/api/jobs", json={"printer": PLA, "path": "nope.gcode"})
    assert missing.status_code == 404, missing.text
