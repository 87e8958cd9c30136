"""Moonraker's 400s are the user's request refused: a typed refusal in Klipper's own words,
over HTTP and over the WebSocket alike, against a real Moonraker + Klippy printer."""

from __future__ import annotations

from collections.abc import AsyncIterator

import httpx
import pytest

from kybercore.errors import (
    ActionRejected,
    FileNotFound,
    InvalidInput,
    KlippyNotReady,
    KyberCoreError,
    MoonrakerRpcError,
    PrinterAuthFailed,
)
from kybercore.moonraker.client import MoonrakerClient
from kybercore.moonraker.events import StatusSnapshot
from kybercore.moonraker.http import http_error
from kybercore.moonraker.refusals import rpc_error
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
async def client(printer: PrinterStack, http: httpx.AsyncClient) -> AsyncIterator[MoonrakerClient]:
    """A client with its session open, so calls can take either path."""
    snapshots: list[StatusSnapshot] = []
    client = MoonrakerClient(
        printer.url,
        http,
        name="shared",
        on_event=lambda e: snapshots.append(e) if isinstance(e, StatusSnapshot) else None,
    )
    client.start()
    await wait_for(lambda: bool(snapshots), what="the session's subscription")
    yield client
    await client.close()


async def test_deleting_a_missing_file_is_not_found(client: MoonrakerClient) -> None:
    with pytest.raises(FileNotFound, match=r"shared: .*nonexistent\.gcode") as over_http:
        await client.delete_file("nonexistent.gcode")
    assert "Invalid file path" in over_http.value.message  # Moonraker's own words
    with pytest.raises(FileNotFound, match="Invalid file path"):
        await client.call("server.files.delete_file", {"path": "gcodes/nonexistent.gcode"})


async def test_a_move_before_homing_is_refused_in_klippers_words(client: MoonrakerClient) -> None:
    await client.gcode_script("M84")  # motors off: Klipper forgets that it was homed
    with pytest.raises(ActionRejected, match="Must home axis first") as over_http:
        await client.gcode_script("G1 Z5")
    assert over_http.value.code == "klipper_refused"
    assert over_http.value.message.startswith("shared: ")
    with pytest.raises(ActionRejected, match="Must home axis first") as over_ws:
        await client.call("printer.gcode.script", {"script": "G1 Z5"})
    assert over_ws.value.code == "klipper_refused"


async def test_a_value_out_of_range_is_invalid_input(client: MoonrakerClient) -> None:
    with pytest.raises(InvalidInput, match=r"Requested temperature \(900\.0\) out of range"):
        await client.gcode_script("M104 S900")
    with pytest.raises(InvalidInput, match="out of range"):
        await client.call("printer.gcode.script", {"script": "M104 S900"})


async def test_starting_a_missing_file_is_not_found(client: MoonrakerClient) -> None:
    with pytest.raises(FileNotFound, match="Unable to open file"):
        await client.print_start("nonexistent.gcode")


async def test_a_missing_argument_is_invalid_input(
    printer: PrinterStack, http: httpx.AsyncClient
) -> None:
    response = await http.get(f"{printer.url}/server/files/metadata")
    error = http_error(response, "/server/files/metadata", "shared")
    assert isinstance(error, InvalidInput)
    assert "No data for argument: filename" in error.message


# What Moonraker 0.11 sends when Klipper's reason spans lines: the JSON-RPC error carries it
# whole, the HTTP answer only "Unknown" (or "Bad Request"), the reason left in the traceback.
SHUTDOWN = (
    "Shutdown due to webhooks request\nOnce the underlying issue is corrected, use the\n"
    '"FIRMWARE_RESTART" command to reset the firmware, reload the\n'
    "config, and restart the host software.\nPrinter is shutdown\n"
)
ERROR_STATE = (
    "Can not update MCU 'mcu' config as it is shutdown\nOnce the underlying issue is "
    'corrected, use the\n"FIRMWARE_RESTART" command to reset the firmware, reload the\n'
    "config, and restart the host software.\nError configuring printer\n"
)


def moonraker_400(message: str, reason: str, path: str) -> httpx.Response:
    traceback = (
        'Traceback (most recent call last):\n  File "app.py", line 720, in _process\n'
        "    raise tornado.web.HTTPError(\n\ntornado.web.HTTPError: HTTP 400: "
        f"{reason}\n"
    )
    body = {"error": {"code": 400, "message": message, "traceback": traceback}}
    return httpx.Response(
        400, json=body, request=httpx.Request("POST", f"http://127.0.0.1:7125{path}")
    )


@pytest.mark.parametrize(
    ("message", "reason", "path", "kind", "words"),
    [
        ("Unknown", SHUTDOWN + "Klipper state: Not ready", "/printer/gcode/script",
         KlippyNotReady, "Shutdown due to webhooks request. Once the underlying"),
        ("Unknown", ERROR_STATE + "Klipper state: Not ready", "/printer/gcode/script",
         KlippyNotReady, "Can not update MCU 'mcu' config as it is shutdown"),
        ("Unknown", SHUTDOWN, "/printer/print/pause", KlippyNotReady, "Printer is shutdown"),
        ("Bad Request", "Bad Request (Invalid file path: gcodes/x.gcode)",
         "/server/files/gcodes/x.gcode", FileNotFound, "Invalid file path: gcodes/x.gcode"),
        ("Unknown", "!! Must home axis first: 0.000 0.000 5.000 [0.000]",
         "/printer/gcode/script", ActionRejected, "Must home axis first"),
    ],
)  # fmt: skip
def test_a_bare_http_message_is_completed_from_the_traceback(
    message: str, reason: str, path: str, kind: type[KyberCoreError], words: str
) -> None:
    error = http_error(moonraker_400(message, reason, path), path, "p1")
    assert type(error) is kind, error
    assert words in error.message
    assert "Unknown" not in error.message
    assert "!!" not in error.message
    assert "\n" not in error.message


def test_moonraker_misbehaving_is_still_a_moonraker_error() -> None:
    request = httpx.Request("GET", "http://127.0.0.1:7125/server/info")
    error = http_error(httpx.Response(500, text="oops", request=request), "/server/info", "p1")
    assert isinstance(error, MoonrakerRpcError)
    assert error.rpc_code == 500


def test_a_file_in_use_is_refused_not_an_auth_failure() -> None:
    request = httpx.Request("POST", "http://127.0.0.1:7125/server/files/upload")
    body = {"error": {"code": 403, "message": "File is loaded, upload not permitted"}}
    error = http_error(httpx.Response(403, json=body, request=request), "/server/files", "p1")
    assert isinstance(error, ActionRejected)
    assert error.code == "file_in_use"
    unauthorized = {"error": {"code": 401, "message": "Unauthorized"}}
    response = httpx.Response(401, json=unauthorized, request=request)
    assert isinstance(http_error(response, "/server/files", "p1"), PrinterAuthFailed)


def test_klippy_away_over_the_websocket_is_not_ready() -> None:
    error = rpc_error(
        {"code": 503, "message": "Klippy Host not connected"}, "printer.print.pause", "p1"
    )
    assert isinstance(error, KlippyNotReady)
