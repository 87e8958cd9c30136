"""The audit log end to end: a real `kybercore serve` in tokens mode over a real printer,
driven over REST and by the real `kybercore` command; ``GET /api/audit`` shows who did
what, to which printer, how it ended and from where, and no token or API key is ever in
it (neither in its answers nor in the database file)."""

from __future__ import annotations

import getpass
import json
import os
import sqlite3
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.sim.stack import PrinterStack, free_port
from tests.helpers import KyberCoreServer, travel_gcode

pytestmark = pytest.mark.integration

API_KEY = "moonraker-key-" + uuid.uuid4().hex
NEW_API_KEY = "moonraker-key-" + uuid.uuid4().hex
CLI_API_KEY = "moonraker-key-" + uuid.uuid4().hex
CLI_ACTOR = f"cli:{getpass.getuser()}"


def kybercore(printers_file: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """The real `kybercore` command, as an admin types it in a shell."""
    return subprocess.run(
        [sys.executable, "-m", "kybercore", *args],
        env={**os.environ, "KYBERCORE_PRINTERS": str(printers_file)},
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def token_from(result: subprocess.CompletedProcess[str]) -> str:
    assert result.returncode == 0, result.stderr
    return result.stdout.strip().splitlines()[-1]


class Farm:
    def __init__(self, folder: Path, server: KyberCoreServer, root: str, olga: str) -> None:
        self.folder = folder
        self.printers_file = folder / "printers.json"
        self.server = server
        self.root = root
        self.olga = olga

    def client(self, token: str | None) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.server.url, headers=headers, timeout=30)

    def audit(self, **filters: Any) -> list[dict[str, Any]]:
        with self.client(self.root) as admin:
            answer = admin.get("/api/audit", params={"limit": 1000, **filters})
        assert answer.status_code == 200, answer.text
        body = answer.json()
        assert body["total"] >= len(body["items"])
        return list(body["items"])


@pytest.fixture
def farm(printer: PrinterStack, tmp_path: Path) -> Iterator[Farm]:
    """One real printer behind a tokens-mode server; tokens made with the real CLI."""
    printers_file = tmp_path / "printers.json"
    write_printers(printers_file, [PrinterConfig(id="p", name="P", moonraker_url=printer.url)])
    root = token_from(kybercore(printers_file, "tokens", "create", "root", "--role", "admin"))
    olga = token_from(kybercore(printers_file, "tokens", "create", "olga", "--role", "operator"))
    server = KyberCoreServer(printers_file, free_port())
    server.start()
    try:
        with httpx.Client(base_url=server.url, timeout=30) as anyone:
            anyone.headers["Authorization"] = f"Bearer {root}"
            for _ in range(300):
                view = anyone.get("/api/printers/p").json()
                if view["connection"] == "online" and view["klippy_state"] == "ready":
                    break
                subprocess.run(["sleep", "0.1"], check=True)  # poll: bounded above
        yield Farm(tmp_path, server, root, olga)
    finally:
        server.stop()


def one(rows: list[dict[str, Any]], **match: Any) -> dict[str, Any]:
    found = [r for r in rows if all(r[k] == v for k, v in match.items())]
    assert len(found) == 1, (match, rows)
    return found[0]


def test_rest_and_cli_actions_are_recorded_with_actor_and_outcome(farm: Farm) -> None:
    with farm.client(farm.olga) as olga, farm.client(farm.root) as root:
        done = olga.post(
            "/api/printers/p/actions/set_temperature",
            json={"extruder": 0, "bed": 0},
            headers={"X-Request-ID": "olga-cools-p"},
        )
        assert done.status_code == 200, done.text
        assert done.headers["x-request-id"] == "olga-cools-p"
        assert olga.post("/api/printers/nope/actions/pause", json={}).status_code == 404
        assert olga.patch("/api/printers/p", json={"notes": "mine"}).status_code == 403
        bulk = olga.post(
            "/api/fleet/actions/set_temperature",
            json={"printer_ids": ["p", "ghost"], "extruder": 0},
        )
        assert bulk.status_code == 200, bulk.text
        added = root.post(
            "/api/printers",
            json={"id": "keyed", "name": "Keyed", "moonraker_url": "http://127.0.0.1:9",
                  "api_key": API_KEY},
        )  # fmt: skip
        assert added.status_code == 201, added.text
        edited = root.patch("/api/printers/keyed", json={"api_key": NEW_API_KEY})
        assert edited.status_code == 200, edited.text
        # Dry runs and reads change nothing: not actions.
        olga.post("/api/printers/p/actions/pause/check", json={})
        olga.get("/api/printers")
    with farm.client(None) as browser:
        assert browser.post("/api/session", json={"token": farm.olga}).status_code == 200
    with farm.client(None) as stranger:
        assert stranger.post("/api/session", json={"token": "kc_" + "x" * 43}).status_code == 401
    # The command line edits printers.json directly, while the server runs.
    edit = kybercore(farm.printers_file, "printers", "edit", "keyed", "--api-key", CLI_API_KEY)
    assert edit.returncode == 0, edit.stderr
    assert "Warning" not in edit.stderr
    missing = kybercore(farm.printers_file, "printers", "edit", "nope", "--notes", "x")
    assert missing.returncode == 1

    rows = farm.audit()
    cooled = one(rows, request_id="olga-cools-p")
    assert cooled["actor"] == "olga"
    assert cooled["role"] == "operator"
    assert cooled["action"] == "printer.set_temperature"
    assert cooled["target"] == "printer:p"
    assert cooled["params"] == {"extruder": 0, "bed": 0}
    assert cooled["outcome"] == "ok"
    assert cooled["client"] == "127.0.0.1"
    assert cooled["at"].endswith(("Z", "+00:00"))
    assert one(rows, action="printer.pause", target="printer:nope")["outcome"] == "unknown_printer"
    refused = one(rows, action="printer.edit", actor="olga")
    assert (refused["target"], refused["outcome"]) == ("printer:p", "forbidden")
    per_printer = [r for r in rows if r["request_id"] == bulk.headers["x-request-id"]]
    assert {r["target"]: r["outcome"] for r in per_printer} == {
        "printer:p": "ok",
        "printer:ghost": "unknown_printer",
    }
    assert all(r["params"] == {"extruder": 0, "bulk": 2} for r in per_printer)
    assert one(rows, action="printer.add")["actor"] == "root"
    assert one(rows, action="printer.edit", actor="root")["params"]["api_key"] == "[redacted]"
    assert one(rows, action="session.login", outcome="ok")["actor"] == "olga"
    assert one(rows, action="session.login", outcome="unauthorized")["actor"] == "anonymous"
    assert not [r for r in rows if r["action"].endswith("check") or "list" in r["action"]]
    cli_edit = one(rows, action="printer.edit", actor=CLI_ACTOR, outcome="ok")
    assert cli_edit["target"] == "printer:keyed"
    assert cli_edit["role"] == "admin"
    assert cli_edit["params"] == {"api_key": "[redacted]"}
    assert one(rows, actor=CLI_ACTOR, target="printer:nope")["outcome"] == "unknown_printer"
    created = [r for r in rows if r["action"] == "token.create"]
    assert {r["params"]["name"]: r["actor"] for r in created} == {
        "root": CLI_ACTOR,
        "olga": CLI_ACTOR,
    }
    # Filters, as the admin's questions: who touched printer p? what did olga do?
    assert {r["action"] for r in farm.audit(target="p")} >= {"printer.set_temperature"}
    assert all(r["actor"] == "olga" for r in farm.audit(actor="olga"))
    assert farm.audit(action="token.create", limit=1) == created[:1]

    # No token and no API key anywhere: not in the answers, not in the database file.
    secrets = (farm.root, farm.olga, API_KEY, NEW_API_KEY, CLI_API_KEY)
    shown = json.dumps(rows)
    assert not [s for s in secrets if s in shown]
    with sqlite3.connect(farm.folder / "kybercore.db") as db:
        stored = json.dumps(db.execute("SELECT * FROM audit").fetchall())
    assert len(json.loads(stored)) == len(rows)
    assert not [s for s in secrets if s in stored]


def test_a_plate_clear_is_recorded_with_its_verdict_and_outcome(farm: Farm) -> None:
    with farm.client(farm.olga) as olga:
        queued = olga.post(
            "/api/jobs",
            files={"file": ("cube.gcode", travel_gcode(8), "application/octet-stream")},
            data={"quantity": "1"},
        )
        assert queued.status_code == 201, queued.text
        job_id = queued.json()["id"]
        for _ in range(1200):  # the queue starts it on p; it prints for a few seconds
            if olga.get("/api/gates").json().get("p", {}).get("state") == "awaiting_clear":
                break
            subprocess.run(["sleep", "0.1"], check=True)  # poll: bounded above (120 s)
        else:
            pytest.fail("printer p never awaited a clear")
        cleared = olga.post("/api/printers/p/clear", json={"verdict": "good", "cause": ""})
        assert cleared.status_code == 200, cleared.text
        again = olga.post("/api/printers/p/clear", json={"verdict": "bad", "cause": "spaghetti"})
        assert again.status_code == 409, again.text

    created = one(farm.audit(action="job.create"), actor="olga")
    assert created["target"] == f"job:{job_id}"
    assert created["params"]["file"] == "cube.gcode"
    assert created["outcome"] == "ok"
    clears = farm.audit(action="plate.clear", target="p")
    assert [(r["actor"], r["role"], r["outcome"]) for r in reversed(clears)] == [
        ("olga", "operator", "ok"),
        ("olga", "operator", again.json()["error"]["code"]),
    ]
    assert [r["params"] for r in reversed(clears)] == [
        {"verdict": "good", "cause": ""},
        {"verdict": "bad", "cause": "spaghetti"},
    ]


def test_only_admins_read_it_and_nobody_edits_it(farm: Farm) -> None:
    with farm.client(farm.olga) as olga, farm.client(farm.root) as root:
        assert olga.get("/api/audit").status_code == 403
        for method in ("POST", "PUT", "PATCH", "DELETE"):
            answer = root.request(method, "/api/audit", json={})
            assert answer.status_code == 405, (method, answer.text)
        paths = root.get("/openapi.json").json()["paths"]
        assert set(paths["/api/audit"]) == {"get"}
        assert not [p for p in paths if p.startswith("/api/audit/")]
        assert root.get("/api/audit", params={"limit": 0}).status_code == 422
        assert root.get("/api/audit", params={"from": "yesterday"}).status_code == 422
        since = root.get("/api/audit", params={"from": "2000-01-01T00:00:00"})  # UTC
        assert since.json()["total"] == 2
        until = root.get("/api/audit", params={"to": "2000-01-01T00:00:00+02:00"})
        assert until.json()["total"] == 0
    # The refused reads and writes above are not actions either.
    assert [r["action"] for r in farm.audit()] == ["token.create", "token.create"]
