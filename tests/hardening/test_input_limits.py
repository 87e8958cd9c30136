"""Bad input through the REST API of a real ``kybercore serve``: each refused with a clear 4xx.

Printer ids, Moonraker URLs (http and https only), file names (no path traversal), G-code
script length and upload size. Every request here is refused before anything reaches a
printer, so the shared fleet is left as it was.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.api.app import MAX_UPLOAD_BYTES
from kybercore.api.models import MAX_SCRIPT_CHARS
from tests.hardening.faults import RssSampler
from tests.helpers import KyberCoreServer

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]

PRINTER = "fleet-a"


@pytest.fixture(scope="module")
def api(kybercore_server: KyberCoreServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=kybercore_server.url, timeout=60) as client:
        yield client


def refused(answer: httpx.Response, status: int, *words: str) -> str:
    """Assert a clear refusal: this status, the error envelope, these words in the message."""
    assert answer.status_code == status, (answer.status_code, answer.text[:500])
    error = answer.json()["error"]
    message = str(error["message"])
    assert error["code"], answer.text
    for word in words:
        assert word.lower() in message.lower(), (word, message)
    return message


def new_printer(**fields: Any) -> dict[str, Any]:
    return {"name": "Hardening", "moonraker_url": "http://127.0.0.1:9", **fields}


# -- printer ids -----------------------------------------------------------------------

BAD_IDS = [
    "Has Capitals",
    "spaces are bad",
    "../etc",
    "a/b",
    "-starts-with-dash",
    "x" * 65,
    "ñandú",
    "",
    "semi;colon",
    "null\x00byte",
]


@pytest.mark.parametrize("printer_id", BAD_IDS)
def test_a_bad_printer_id_is_refused(api: httpx.Client, printer_id: str) -> None:
    answer = api.post("/api/printers", json=new_printer(id=printer_id))
    refused(answer, 422, "id")


def test_an_unknown_printer_id_is_a_clear_404(api: httpx.Client) -> None:
    for printer_id in ("no-such-printer", "x" * 5000, "%2e%2e"):
        message = refused(api.get(f"/api/printers/{printer_id}"), 404, "no printer with id")
        assert "GET /api/printers" in message
        refused(api.post(f"/api/printers/{printer_id}/actions/home"), 404, "no printer")


def test_the_id_of_a_printer_cannot_be_changed(api: httpx.Client) -> None:
    refused(api.patch(f"/api/printers/{PRINTER}", json={"id": "other"}), 422, "id")


# -- URLs ------------------------------------------------------------------------------

BAD_URLS = [
    ("ftp://10.0.0.5:7125", "http://"),
    ("file:///etc/passwd", "http://"),
    ("javascript:alert(1)", "http://"),
    ("ws://10.0.0.5:7125", "http://"),
    ("mailto:admin@example.com", "http://"),
    ("10.0.0.5:7125/server/info", "http://"),
    ("http://user:secret@10.0.0.5:7125", "credentials"),
    ("http://", "host"),
    ("http://10.0.0.5:99999", "port"),
    ("http://10.0.0.5:7125/?x=1", "query"),
    ("http://10.0.0.5:7125/#frag", "fragment"),
    ("http://10.0.0.5 :7125", "spaces"),
    ("http://10.0.0.5:7125/\nHost: evil", "control"),
    ("http://h/" + "a" * 2100, "2048"),
]


@pytest.mark.parametrize(("url", "reason"), BAD_URLS)
def test_a_bad_moonraker_url_is_refused(api: httpx.Client, url: str, reason: str) -> None:
    refused(api.post("/api/printers", json=new_printer(moonraker_url=url)), 422, "url", reason)
    refused(api.patch(f"/api/printers/{PRINTER}", json={"moonraker_url": url}), 422, reason)


# -- file names ------------------------------------------------------------------------

TRAVERSALS = [
    "../printer.cfg",
    "../../etc/passwd",
    "/etc/passwd",
    "a/../../b.gcode",
    "a/./b.gcode",
    "..\\..\\config\\printer.cfg",
    "a//b.gcode",
    "file\x00.gcode",
    "line\nbreak.gcode",
    "",
    "x" * 1025,
]


@pytest.mark.parametrize("name", TRAVERSALS)
def test_a_file_name_outside_gcodes_is_refused(api: httpx.Client, name: str) -> None:
    base = f"/api/printers/{PRINTER}/files"
    message = refused(api.get(f"{base}/metadata", params={"filename": name}), 422)
    # Refused by the path rule, or (too long) by the schema that now documents the limit.
    assert "not a valid file name" in message or "query.filename" in message, message
    thumb = name if name.endswith((".png", ".jpg")) else name + ".png"
    if name and len(thumb) <= 1024:
        refused(api.get(f"{base}/thumbnail", params={"path": thumb}), 422, "valid file name")
    if name and "\x00" not in name and "\n" not in name:
        answer = api.post(base, files={"file": (name, b"G28\n", "application/octet-stream")})
        refused(answer, 422)
    check = api.post(f"/api/printers/{PRINTER}/actions/start/check", json={"filename": name})
    assert check.status_code in (200, 422), check.text
    if check.status_code == 200:
        # A dry run may answer with a verdict, but it must block, not accept, the name.
        assert check.json()["level"] == "block", check.text


def test_only_images_are_served_as_thumbnails(api: httpx.Client) -> None:
    answer = api.get(f"/api/printers/{PRINTER}/files/thumbnail", params={"path": "cube.gcode"})
    refused(answer, 422, ".png")


# -- G-code script length ----------------------------------------------------------------


def test_a_script_over_the_limit_is_refused_before_reaching_the_printer(
    api: httpx.Client,
) -> None:
    script = ("M117 " + "x" * 58 + "\n") * (MAX_SCRIPT_CHARS // 64 + 1)
    assert len(script) > MAX_SCRIPT_CHARS
    refused(api.post(f"/api/printers/{PRINTER}/gcode", json={"script": script}), 422, "script")
    refused(api.post(f"/api/printers/{PRINTER}/gcode", json={"script": ""}), 422, "script")
    # Not a string, not an object: refused by the schema, not by a crash.
    refused(api.post(f"/api/printers/{PRINTER}/gcode", json={"script": 42}), 422, "script")
    refused(api.post(f"/api/printers/{PRINTER}/gcode", json=["G28"]), 422)


# -- upload size -------------------------------------------------------------------------


def _upload_too_big(api: httpx.Client, tmp_path: Path, name: str) -> httpx.Response:
    big = tmp_path / name
    with big.open("wb") as handle:  # sparse: costs no disk, streamed by httpx
        handle.truncate(MAX_UPLOAD_BYTES + 1)
    with big.open("rb") as handle:
        return api.post(
            f"/api/printers/{PRINTER}/files",
            files={"file": (name, handle, "application/octet-stream")},
        )


def _server_pid(server: KyberCoreServer) -> int:
    assert server._proc is not None  # the test measures its memory
    return server._proc.pid


def test_an_upload_over_the_limit_is_refused(
    api: httpx.Client, kybercore_server: KyberCoreServer, tmp_path: Path
) -> None:
    started = time.monotonic()
    with RssSampler(_server_pid(kybercore_server)) as memory:
        answer = _upload_too_big(api, tmp_path, "too-big.gcode")
    elapsed = time.monotonic() - started
    status = answer.status_code
    assert status in (413, 422), answer.text[:300]
    refused(answer, status, f"{MAX_UPLOAD_BYTES // 2**20} MiB")
    print(
        f"\nan upload of {MAX_UPLOAD_BYTES // 2**20} MiB + 1 byte was refused with {status} in "
        f"{elapsed:.1f} s; the server's RSS grew by up to {memory.growth / 2**20:.0f} MiB"
    )
    files = api.get(f"/api/printers/{PRINTER}/files").json()
    assert "too-big.gcode" not in {f["path"] for f in files}


def test_an_oversize_upload_is_refused_without_holding_it_in_memory(
    api: httpx.Client, kybercore_server: KyberCoreServer, tmp_path: Path
) -> None:
    """Refused from its size, not after reading 512 MiB into the server's memory."""
    with RssSampler(_server_pid(kybercore_server)) as memory:
        answer = _upload_too_big(api, tmp_path, "too-big-2.gcode")
    assert answer.status_code in (413, 422)
    assert memory.growth < 64 * 2**20, f"the server grew by {memory.growth / 2**20:.0f} MiB"
