"""``POST /api/printers/{id}/gcode`` answers with what Klipper said, and
``GET /api/printers/{id}/console`` with the printer's recent console: a real
`kybercore serve` over real Moonraker + Klippy printers."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator

import httpx
import pytest

from kybercore.fleet.actions import klipper_errors
from tests.helpers import KyberCoreServer

pytestmark = pytest.mark.integration


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


async def gcode(api: httpx.AsyncClient, script: str) -> dict[str, object]:
    answer = await api.post("/api/printers/fleet-a/gcode", json={"script": script})
    assert answer.status_code == 200, answer.text
    body: dict[str, object] = answer.json()
    return body


async def test_m115_answers_with_the_firmware_line(api: httpx.AsyncClient) -> None:
    body = await gcode(api, "M115")
    assert body["ok"] is True
    assert body["code"] == "ok"
    assert body["message"] == "G-code done."
    response = body["response"]
    assert isinstance(response, list)
    assert any(line.startswith("// FIRMWARE_NAME:Klipper") for line in response), response


async def test_an_unknown_command_answers_with_klippers_error(api: httpx.AsyncClient) -> None:
    # Klipper 0.12 reports an unknown command as information ("// Unknown command"), and
    # Moonraker's call succeeds: the answer quotes Klipper rather than saying "done".
    body = await gcode(api, "FOO_BAR")
    assert body["response"] == ['// Unknown command:"FOO_BAR"']
    assert body["ok"] is True  # what Moonraker said; the message says what Klipper said
    assert body["message"] != "G-code done."
    assert 'Unknown command:"FOO_BAR"' in str(body["message"])


async def test_an_error_line_of_a_command_that_ran_is_quoted(api: httpx.AsyncClient) -> None:
    # RESPOND TYPE=error prints a "!!" line while the call itself succeeds: the case of a
    # Klipper (or a macro) that reports its failure as a response.
    body = await gcode(api, "RESPOND TYPE=error MSG=nozzle_clogged")
    assert body["response"] == ["!! nozzle_clogged"]
    assert "Klipper answered with an error: nozzle_clogged" in str(body["message"])


async def test_several_lines_come_back_in_order(api: httpx.AsyncClient) -> None:
    marker = uuid.uuid4().hex[:8]
    body = await gcode(api, f"RESPOND MSG=first-{marker}\nRESPOND MSG=second-{marker}")
    assert body["response"] == [f"echo: first-{marker}", f"echo: second-{marker}"]


async def test_a_command_klipper_refuses_is_still_an_error(api: httpx.AsyncClient) -> None:
    await gcode(api, "M84")  # motors off: not homed
    answer = await api.post("/api/printers/fleet-a/gcode", json={"script": "G1 Z5"})
    assert answer.status_code == 409, answer.text
    assert "Must home axis first" in answer.json()["error"]["message"]


async def test_the_console_history_is_the_printers_gcode_store(api: httpx.AsyncClient) -> None:
    marker = uuid.uuid4().hex[:8]
    await gcode(api, f"RESPOND MSG=history-{marker}")
    answer = await api.get("/api/printers/fleet-a/console", params={"count": 5})
    assert answer.status_code == 200, answer.text
    entries = answer.json()
    assert len(entries) == 5
    # Oldest first: the command, then Klipper's response to it, last.
    assert entries[-2]["type"] == "command"
    assert entries[-2]["message"] == f"RESPOND MSG=history-{marker}"
    assert entries[-1] == {
        "message": f"echo: history-{marker}",
        "time": entries[-1]["time"],
        "type": "response",
    }
    assert entries[-2]["time"] <= entries[-1]["time"]

    too_many = await api.get("/api/printers/fleet-a/console", params={"count": 5000})
    assert too_many.status_code == 422
    missing = await api.get("/api/printers/nope/console")
    assert missing.status_code == 404


@pytest.mark.parametrize(
    ("lines", "errors"),
    [
        (["// FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.12"], []),
        (['// Unknown command:"FOO_BAR"'], ['Unknown command:"FOO_BAR"']),
        # A firmware that marks an unknown command as an error.
        (["!! Unknown command: FOO_BAR"], ["Unknown command: FOO_BAR"]),
        (["echo: x", "!! boom", "ok"], ["boom"]),
        (["// Klipper state: Ready"], []),
    ],
)
def test_klippers_error_lines(lines: list[str], errors: list[str]) -> None:
    assert klipper_errors(lines) == errors
