"""The fleet backend end to end: a real `kybercore serve` over real Moonraker + Klippy printers,
driven through its REST API and watched through `/ws` as a browser would."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import time
import uuid
from collections.abc import AsyncIterator, Callable

import httpx
import pytest

from kybercore.registry.store import read_printers
from kybercore.sim.stack import PrinterStack, free_port
from tests.browser_mirror import BrowserMirror
from tests.helpers import KyberCoreServer, travel_gcode

pytestmark = pytest.mark.integration

FLEET = ("fleet-a", "fleet-b", "fleet-c")
SECRET = "sk-kybercore-test-SECRET-" + uuid.uuid4().hex

# Promises, each with at least 5x slack over its figure on an idle machine (measured by
# `python -m bench.promises`, which prints the precise figures; see bench/README.md).
LIVE_WITHIN = 2.0
"""A status change reaches the browser: idle median 0.16-0.23 s, max 0.35 s (5.7x)."""
OFFLINE_WITHIN = 2.0
"""Moonraker gone (its process has exited) -> the browser shows the printer offline: idle
0-21 ms (the session notices while Moonraker exits; the hub publishes within a 0.1 s tick)."""
REFUSED_WITHIN = 1.0
"""An action on an offline printer -> 503: idle 3-4 ms. Anything that waited on the printer
would take at least PROBE_AFTER (1.5 s) before giving up."""


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


@pytest.fixture
async def mirror(kybercore_server: KyberCoreServer) -> AsyncIterator[BrowserMirror]:
    async with BrowserMirror(kybercore_server.ws_url) as browser:
        yield browser


def job_state(mirror: BrowserMirror, printer: str) -> Callable[[], str]:
    return lambda: str(mirror.printers.get(printer, {}).get("job", {}).get("state", ""))


async def test_fleet_view_shows_every_printer_live(
    api: httpx.AsyncClient, mirror: BrowserMirror
) -> None:
    # Klippy reports its first thermistor readings a moment after `ready`.
    await mirror.wait(
        lambda: all(
            (mirror.printers[p][heater]["temperature"] or 0) > 10
            for p in FLEET
            for heater in ("extruder", "bed")
        ),
        what="live temperatures",
    )
    # The fleet list is what the browsers were sent: the same published views.
    views = (await api.get("/api/printers")).json()
    assert tuple(v["id"] for v in views[:3]) == FLEET
    for view in views[:3]:
        assert view["connection"] == "online"
        assert view["klippy_state"] == "ready"
        assert view["extruder"]["temperature"] == pytest.approx(25, abs=5)
        assert view["bed"]["temperature"] == pytest.approx(25, abs=5)
    # Limits read from each printer's own Klippy configfile, once it is connected.
    await mirror.wait(
        lambda: all(mirror.printers[p]["capabilities"]["build_volume"] for p in FLEET),
        what="capabilities from configfile",
    )
    heights = [mirror.printers[p]["capabilities"]["build_volume"]["z"] for p in FLEET]
    assert heights == [250, 400, 180]
    assert mirror.printers["fleet-c"]["capabilities"]["nozzle_diameter"] == 0.6

    # A status change on one printer reaches the browser, live.
    answer = await api.post("/api/printers/fleet-a/gcode", json={"script": "M104 S45"})
    assert answer.status_code == 200, answer.text
    try:
        took = await mirror.wait(
            lambda: mirror.printers["fleet-a"]["extruder"]["target"] == 45, what="target 45"
        )
        assert took < LIVE_WITHIN
    finally:
        await api.post("/api/printers/fleet-a/gcode", json={"script": "M104 S0"})


async def test_start_pause_resume_cancel_through_rest(
    api: httpx.AsyncClient, mirror: BrowserMirror
) -> None:
    name = f"job-{uuid.uuid4().hex[:6]}.gcode"
    upload = await api.post(
        "/api/printers/fleet-b/files", files={"file": (name, travel_gcode(moves=40))}
    )
    assert upload.status_code == 201, upload.text
    assert name in [f["path"] for f in (await api.get("/api/printers/fleet-b/files")).json()]

    async def act(action: str, expected: str, **body: object) -> None:
        answer = await api.post(f"/api/printers/fleet-b/actions/{action}", json=body)
        assert answer.status_code == 200, answer.text
        assert answer.json()["ok"] is True
        await mirror.wait(lambda: job_state(mirror, "fleet-b")() == expected, what=expected)
        view = (await api.get("/api/printers/fleet-b")).json()
        assert view["job"]["state"] == expected

        def told() -> bool:
            return action in [e["action"] for e in mirror.events("action", "fleet-b")]

        # The action's own event may come a tick after the state it led to.
        await mirror.wait(told, what=f"the {action} event")

    await act("start", "printing", filename=name)
    view = (await api.get("/api/printers/fleet-b")).json()
    assert view["job"]["filename"] == name
    assert view["actions"]["pause"]
    assert not view["actions"]["start"]
    await act("pause", "paused")
    await act("resume", "printing")
    await act("cancel", "cancelled")
    actions = [(e["action"], e["ok"]) for e in mirror.events("action", "fleet-b")]
    assert actions == [
        ("upload", True),
        ("start", True),
        ("pause", True),
        ("resume", True),
        ("cancel", True),
    ]


async def test_wrong_state_and_unknown_printer(api: httpx.AsyncClient) -> None:
    answer = await api.post("/api/printers/fleet-c/actions/pause")
    assert answer.status_code == 409
    error = answer.json()["error"]
    assert error["code"] == "pause_not_printing"
    assert "nothing to pause" in error["message"].lower()
    assert error["reasons"][0]["es"]
    missing = await api.post("/api/printers/no-such-printer/actions/pause")
    assert missing.status_code == 404
    assert "no-such-printer" in missing.json()["error"]["message"]
    bad = await api.post("/api/printers/fleet-c/actions/set_temperature", json={"extruder": 999})
    assert bad.status_code == 422
    nothing = await api.post("/api/printers/fleet-c/actions/start", json={"filename": "nope.gcode"})
    assert nothing.status_code == 404  # a missing file, not a malformed request
    assert "Upload it first" in nothing.json()["error"]["message"]


async def test_a_printer_going_offline_and_coming_back(
    api: httpx.AsyncClient,
    mirror: BrowserMirror,
    start_stack: Callable[..., PrinterStack],
) -> None:
    stack = start_stack("flaky")
    added = await api.post(
        "/api/printers", json={"id": "flaky", "name": "Flaky", "moonraker_url": stack.url}
    )
    assert added.status_code == 201, added.text
    try:
        await mirror.wait(
            lambda: mirror.printers.get("flaky", {}).get("klippy_state") == "ready",
            what="the new printer ready",
        )
        stack.stop_moonraker()
        took = await mirror.wait(
            lambda: mirror.printers["flaky"]["connection"] == "offline", what="offline"
        )
        assert took < OFFLINE_WITHIN
        started = time.monotonic()
        answer = await api.post("/api/printers/flaky/actions/home")
        assert answer.status_code == 503
        assert time.monotonic() - started < REFUSED_WITHIN
        assert "reconnects by itself" in answer.json()["error"]["message"]
        # Other printers are unaffected.
        assert (await api.get("/api/printers/fleet-a")).json()["connection"] == "online"

        stack.start_moonraker()
        await mirror.wait(
            lambda: (
                mirror.printers["flaky"]["connection"] == "online"
                and mirror.printers["flaky"]["klippy_state"] == "ready"
            ),
            timeout=30,
            what="back online",
        )
        assert (await api.post("/api/printers/flaky/actions/home")).status_code == 200
    finally:
        assert (await api.delete("/api/printers/flaky")).status_code == 204
        stack.stop()
    await mirror.wait(lambda: "flaky" not in mirror.printers, what="removal over /ws")
    assert (await api.get("/api/printers/flaky")).status_code == 404


async def test_edit_printers_over_rest_and_cli_while_running(
    api: httpx.AsyncClient, mirror: BrowserMirror, kybercore_server: KyberCoreServer
) -> None:
    offline_url = f"http://127.0.0.1:{free_port()}"
    created = await api.post(
        "/api/printers",
        json={"name": "Spare Voron", "moonraker_url": offline_url, "api_key": SECRET},
    )
    assert created.status_code == 201, created.text
    spare = created.json()
    assert spare["id"] == "spare-voron"
    assert spare["api_key_set"] is True
    await mirror.wait(lambda: "spare-voron" in mirror.printers, what="spare over /ws")
    await mirror.wait(
        lambda: mirror.printers["spare-voron"]["connection"] == "offline", what="spare offline"
    )

    edited = await api.patch("/api/printers/spare-voron", json={"name": "Spare", "tags": ["x"]})
    assert edited.status_code == 200
    await mirror.wait(lambda: mirror.printers["spare-voron"]["name"] == "Spare", what="rename")
    invalid = await api.patch("/api/printers/spare-voron", json={"moonraker_url": "ftp://x"})
    assert invalid.status_code == 422
    assert "http://" in invalid.json()["error"]["message"]

    cli = [
        sys.executable,
        "-m",
        "kybercore",
        "printers",
        "--printers-file",
        str(kybercore_server.printers_file),
    ]
    subprocess.run(
        [*cli, "add", "CLI Printer", "--url", f"http://127.0.0.1:{free_port()}",
         "--id", "from-cli", "--api-key", SECRET],
        check=True, capture_output=True,
    )  # fmt: skip
    await mirror.wait(lambda: "from-cli" in mirror.printers, what="CLI add picked up")
    subprocess.run([*cli, "edit", "from-cli", "--location", "Shelf 9"], check=True)
    await mirror.wait(
        lambda: mirror.printers["from-cli"]["location"] == "Shelf 9", what="CLI edit picked up"
    )
    subprocess.run([*cli, "remove", "from-cli", "--yes"], check=True, capture_output=True)
    await mirror.wait(lambda: "from-cli" not in mirror.printers, what="CLI remove picked up")
    assert (await api.delete("/api/printers/spare-voron")).status_code == 204

    stored = read_printers(kybercore_server.printers_file)
    assert [p.id for p in stored] == ["fleet-a", "fleet-b", "fleet-c"]

    # The key went to printers.json and nowhere else.
    everything = json.dumps((await api.get("/api/printers")).json()) + "".join(mirror.raw)
    assert mirror.raw
    assert SECRET not in everything
    assert SECRET not in created.text + edited.text
    assert SECRET not in kybercore_server.log.read_text()


async def test_console_responses_reach_only_clients_that_asked(
    api: httpx.AsyncClient, kybercore_server: KyberCoreServer
) -> None:
    async with (
        BrowserMirror(kybercore_server.ws_url) as watcher,
        BrowserMirror(kybercore_server.ws_url) as other,
    ):
        await watcher.send({"type": "console", "printers": ["fleet-c"]})
        marker = f"kc-{uuid.uuid4().hex[:8]}"
        # The subscription travels on the socket; retry the echo until it is in effect.
        for _ in range(20):
            answer = await api.post(
                "/api/printers/fleet-c/gcode", json={"script": f"M118 {marker}"}
            )
            assert answer.status_code == 200
            try:
                await watcher.wait(
                    lambda: any(marker in e["message"] for e in watcher.events("gcode_response")),
                    timeout=0.5,
                )
                break
            except AssertionError:
                continue
        else:
            raise AssertionError("no G-code response reached the subscribed client")
        assert all(e["printer"] == "fleet-c" for e in watcher.events("gcode_response"))
        assert other.events("gcode_response") == []


async def test_openapi_documents_every_endpoint_and_model(api: httpx.AsyncClient) -> None:
    spec = (await api.get("/openapi.json")).json()
    paths = set(spec["paths"])
    assert {
        "/api/printers",
        "/api/printers/{printer_id}",
        "/api/printers/{printer_id}/actions/{action}",
        "/api/printers/{printer_id}/actions/{action}/check",
        "/api/printers/{printer_id}/gcode",
        "/api/printers/{printer_id}/files",
        "/api/fleet/actions/{action}",
        "/api/health",
    } <= paths
    schemas = spec["components"]["schemas"]
    for model in ("PrinterView", "PrinterCreate", "PrinterUpdate", "ActionResult", "ErrorResponse"):
        assert schemas[model].get("description"), f"{model} has no description"
    for name, field in schemas["PrinterCreate"]["properties"].items():
        assert field.get("description"), f"PrinterCreate.{name} has no description"
    for path, methods in spec["paths"].items():
        for method, operation in methods.items():
            assert operation.get("description") or operation.get("summary"), (method, path)


async def test_warnings_need_confirmation_and_say_why(api: httpx.AsyncClient) -> None:
    script = {"script": "G90\nG1 X1000 F3000"}  # beyond fleet-a's 220 mm
    answer = await api.post("/api/printers/fleet-a/gcode", json=script)
    assert answer.status_code == 409
    error = answer.json()["error"]
    assert error["code"] == "confirmation_required"
    assert [r["code"] for r in error["reasons"]] == ["gcode_move_outside_volume"]
    assert error["reasons"][0]["es"]


async def test_invalid_fields_are_named_in_both_languages(api: httpx.AsyncClient) -> None:
    answer = await api.post("/api/printers", json={"name": "", "moonraker_url": "ftp://x"})
    assert answer.status_code == 422
    fields = {f["field"]: f for f in answer.json()["error"]["fields"]}
    assert set(fields) == {"name", "moonraker_url"}
    assert "http://" in fields["moonraker_url"]["en"]
    assert fields["name"]["es"] == "Es demasiado corto."


async def test_delete_a_file_but_never_outside_the_gcodes_folder(api: httpx.AsyncClient) -> None:
    name = f"delete-me-{uuid.uuid4().hex[:6]}.gcode"
    files = {"file": (name, travel_gcode(moves=2))}
    assert (await api.post("/api/printers/fleet-c/files", files=files)).status_code == 201
    assert (
        await api.delete("/api/printers/fleet-c/files", params={"path": name})
    ).status_code == 204
    assert name not in [f["path"] for f in (await api.get("/api/printers/fleet-c/files")).json()]
    escape = await api.delete(
        "/api/printers/fleet-c/files", params={"path": "../config/printer.cfg"}
    )
    assert escape.status_code == 422
    assert "not a valid file name" in escape.json()["error"]["message"]


async def test_an_oversized_upload_is_refused_before_it_is_read(
    kybercore_server: KyberCoreServer,
) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", kybercore_server.port)
    writer.write(
        b"POST /api/printers/fleet-c/files HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: multipart/form-data; boundary=x\r\n"
        b"Content-Length: 900000000\r\n\r\n"
    )
    await writer.drain()
    status_line = await asyncio.wait_for(reader.readline(), 5)
    writer.close()
    assert b" 413 " in status_line


async def test_a_broken_edit_on_disk_keeps_the_last_good_fleet(
    api: httpx.AsyncClient, mirror: BrowserMirror, kybercore_server: KyberCoreServer
) -> None:
    path = kybercore_server.printers_file
    good = path.read_text()
    try:
        path.write_text(good[: len(good) // 2])  # a half-written file
        await mirror.wait(lambda: bool(mirror.events("config")), what="the refused edit")
        refused = mirror.events("config")[-1]
        assert refused["ok"] is False
        assert "line" in refused["message"]
        health = (await api.get("/api/health")).json()
        assert health["config_error"]
        assert health["printers"] >= 3
        assert [v["id"] for v in (await api.get("/api/printers")).json()][:3] == list(FLEET)
        assert path.read_text() == good[: len(good) // 2]  # never overwritten
    finally:
        path.write_text(good)
    await mirror.wait(lambda: mirror.events("config")[-1]["ok"] is True, what="the reload")
    assert (await api.get("/api/health")).json()["config_error"] is None


async def test_a_printer_is_saved_only_once_its_moonraker_answers_when_asked(
    api: httpx.AsyncClient, kybercore_server: KyberCoreServer, printer: PrinterStack
) -> None:
    """``?check=true`` (the dashboard's add): a Moonraker that does not answer is a 503
    saying why, and nothing is saved; one that answers is added. The same Moonraker twice
    is refused whatever the check."""
    before = kybercore_server.printers_file.read_text()
    dead = f"127.0.0.1:{free_port()}"  # as people type it: no scheme
    refused = await api.post(
        "/api/printers?check=true", json={"id": "probe", "name": "Probe", "moonraker_url": dead}
    )
    assert refused.status_code == 503, refused.text
    error = refused.json()["error"]
    assert error["code"] == "printer_unreachable"
    assert f"http://{dead}" in error["message"]
    assert "Traceback" not in error["message"]
    assert kybercore_server.printers_file.read_text() == before

    body = {"id": "probe", "name": "Probe", "moonraker_url": printer.url.removeprefix("http://")}
    try:
        added = await api.post("/api/printers?check=true", json=body)
        assert added.status_code == 201, added.text
        assert added.json()["moonraker_url"] == printer.url
        twice = await api.post("/api/printers", json={**body, "id": "probe-2"})
        assert twice.status_code == 422, twice.text
        assert twice.json()["error"]["reasons"][0]["code"] == "url_taken"
    finally:
        await api.delete("/api/printers/probe")


async def test_bulk_starts_are_paced_by_the_server(
    api: httpx.AsyncClient, mirror: BrowserMirror
) -> None:
    name = f"paced-{uuid.uuid4().hex[:6]}.gcode"
    for printer in ("fleet-a", "fleet-b"):
        answer = await api.post(
            f"/api/printers/{printer}/files", files={"file": (name, travel_gcode(moves=40))}
        )
        assert answer.status_code == 201, answer.text
    stagger = 3.0
    printing_at: dict[str, float] = {}

    async def watch(printer: str) -> None:
        await mirror.wait(lambda: job_state(mirror, printer)() == "printing", what=printer)
        printing_at[printer] = time.monotonic()

    watchers = [asyncio.ensure_future(watch(p)) for p in ("fleet-a", "fleet-b")]
    sent = time.monotonic()
    answer = await api.post(
        "/api/fleet/actions/start",
        json={"printer_ids": ["fleet-a", "fleet-b"], "filename": name, "stagger_seconds": stagger},
    )
    took = time.monotonic() - sent
    assert answer.status_code == 200, answer.text
    assert [r["ok"] for r in answer.json()["results"]] == [True, True]
    await asyncio.gather(*watchers)
    # Lower bounds only (a busy machine can stretch them, never shorten them): the server
    # waited, and the second printer started that much after the first (less the browser
    # feed's coalescing, a status interval and a tick).
    assert took >= stagger
    assert printing_at["fleet-b"] - printing_at["fleet-a"] >= stagger - 0.5
    cancel = await api.post(
        "/api/fleet/actions/cancel", json={"printer_ids": ["fleet-a", "fleet-b"]}
    )
    assert [r["ok"] for r in cancel.json()["results"]] == [True, True], cancel.text
