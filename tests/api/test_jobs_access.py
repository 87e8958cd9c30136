"""The job queue's HTTP edge on an empty fleet: who may read and change it, and how it
refuses what it cannot take (unknown ids, bad forms, files that are not G-code, bodies it
cannot read), each in the one error envelope."""

from __future__ import annotations

import httpx
import pytest

from kybercore.api.auth import TokenStore, tokens_path_for
from tests.api.conftest import StartEdge
from tests.helpers import travel_gcode

pytestmark = pytest.mark.integration

GCODE = travel_gcode(moves=2)


def test_viewers_read_the_queue_and_operators_change_it(edge_server: StartEdge) -> None:
    server, admin = edge_server(tokens=True)
    store = TokenStore(tokens_path_for(server.printers_file))
    _, viewer = store.create("watcher", "viewer")
    _, operator = store.create("shift", "operator")

    def as_(token: str) -> httpx.Client:
        return httpx.Client(
            base_url=server.url, headers={"Authorization": f"Bearer {token}"}, timeout=10
        )

    with as_(viewer) as client:
        for path in ("/api/jobs", "/api/queue", "/api/gates"):
            assert client.get(path).status_code == 200, path
        refused = client.post("/api/queue", json={"paused": True})
        assert refused.status_code == 403, refused.text
        assert "operator" in refused.json()["error"]["message"]
        upload = client.post("/api/jobs", files={"file": ("a.gcode", GCODE)})
        assert upload.status_code == 403, upload.text
    with as_(operator) as client:
        paused = client.post("/api/queue", json={"paused": True})
        assert paused.status_code == 200, paused.text
        assert paused.json()["paused"] is True
        assert client.post("/api/queue", json={"paused": False}).json()["paused"] is False
    anonymous = httpx.get(f"{server.url}/api/jobs", timeout=10)
    assert anonymous.status_code == 401
    assert admin  # the server runs in tokens mode because this token exists


def test_unknown_jobs_and_printers_are_404s(edge_server: StartEdge) -> None:
    server, _ = edge_server()
    with httpx.Client(base_url=server.url, timeout=10) as client:
        for method, path, body in (
            ("GET", "/api/jobs/4242", None),
            ("GET", "/api/jobs/4242/why", None),
            ("GET", "/api/jobs/4242/attempts", None),
            ("PATCH", "/api/jobs/4242", {"priority": 1}),
            ("DELETE", "/api/jobs/4242", None),
            ("POST", "/api/jobs/4242/move", {"before": None}),
            ("POST", "/api/jobs/4242/requeue", None),
            ("POST", "/api/printers/nope/clear", {"verdict": "good"}),
            ("POST", "/api/printers/nope/hold", {"reason": "x"}),
            ("POST", "/api/printers/nope/release", None),
        ):
            answer = client.request(method, path, json=body)
            assert answer.status_code == 404, (method, path, answer.text)
            assert answer.json()["error"]["message"], (method, path)


def test_what_the_queue_cannot_take_is_refused_in_words(edge_server: StartEdge) -> None:
    server, _ = edge_server()
    with httpx.Client(base_url=server.url, timeout=10) as client:
        not_gcode = client.post("/api/jobs", files={"file": ("notes.txt", b"hello")})
        assert not_gcode.status_code == 422, not_gcode.text
        assert ".gcode" in not_gcode.json()["error"]["message"]

        bad_fields = client.post(
            "/api/jobs",
            files={"file": ("a.gcode", GCODE)},
            data={"quantity": "0", "nozzle": "wide", "not_before": "tomorrow"},
        )
        assert bad_fields.status_code == 422, bad_fields.text
        fields = {f["field"] for f in bad_fields.json()["error"]["fields"]}
        assert fields == {"quantity", "nozzle", "not_before"}
        assert all(f["es"] for f in bad_fields.json()["error"]["fields"])

        no_file = client.post("/api/jobs", data={"quantity": "2"})
        assert no_file.status_code == 422, no_file.text

        plain = client.post("/api/jobs", content=b"G28", headers={"Content-Type": "text/plain"})
        assert plain.status_code == 422, plain.text
        assert "multipart/form-data" in plain.json()["error"]["message"]

        bad_json = client.post("/api/jobs", json={"printer": "x"})
        assert bad_json.status_code == 422, bad_json.text
        assert "path" in {f["field"] for f in bad_json.json()["error"]["fields"]}

        broken = client.post(
            "/api/queue", content=b'{"paused": tru', headers={"Content-Type": "application/json"}
        )
        assert broken.status_code == 422, broken.text
        [field] = broken.json()["error"]["fields"]
        assert field["field"] == "body"
        assert field["en"].startswith("The body is not valid JSON at character 11 (Expecting")
        assert field["es"].startswith("El cuerpo no es JSON válido en el carácter 11")
        assert "Send a JSON object" in broken.json()["error"]["message"]

        escaping = client.post("/api/jobs", json={"printer": "x", "path": "../printer.cfg"})
        assert escaping.status_code == 422, escaping.text

        bad_clear = client.post("/api/printers/x/clear", json={"verdict": "maybe"})
        assert bad_clear.status_code == 422, bad_clear.text
        empty_hold = client.post("/api/printers/x/hold", json={"reason": "  "})
        assert empty_hold.status_code == 422, empty_hold.text
        assert client.get("/api/jobs").json() == []
