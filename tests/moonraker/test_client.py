"""Every MoonrakerClient HTTP method, against a real Moonraker + Klippy printer."""

from __future__ import annotations

import asyncio
import hashlib
import uuid

import httpx
import pytest

from kybercore.errors import MoonrakerRpcError, PrinterAuthFailed
from kybercore.moonraker.client import MoonrakerClient
from kybercore.moonraker.events import KlippyChanged
from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
def client(printer: PrinterStack, http: httpx.AsyncClient) -> MoonrakerClient:
    return MoonrakerClient(printer.url, http, name="shared")


async def print_state(client: MoonrakerClient) -> str:
    status = await client.objects_query({"print_stats": ["state"]})
    return str(status["print_stats"]["state"])


async def wait_print_state(client: MoonrakerClient, state: str, timeout: float = 20.0) -> None:
    seen = ""
    deadline = asyncio.get_running_loop().time() + timeout
    while (seen := await print_state(client)) != state:
        assert asyncio.get_running_loop().time() < deadline, f"still {seen!r}, wanted {state!r}"
        await asyncio.sleep(0.1)  # poll: wait for the print state, deadline above


async def test_info_objects_and_query(client: MoonrakerClient) -> None:
    info = await client.printer_info()
    assert info["state"] == "ready"
    server = await client.server_info()
    assert server["klippy_state"] == "ready"
    assert server["klippy_connected"] is True
    objects = await client.objects_list()
    assert {"toolhead", "extruder", "heater_bed", "print_stats", "webhooks"} <= set(objects)
    status = await client.objects_query({"extruder": ["temperature", "target"], "webhooks": None})
    assert set(status["extruder"]) == {"temperature", "target"}
    assert status["webhooks"]["state"] == "ready"


async def test_gcode_script_homes_and_reaches_the_console(client: MoonrakerClient) -> None:
    assert await client.gcode_script("G28") == "ok"
    status = await client.objects_query({"toolhead": ["position", "homed_axes"]})
    assert status["toolhead"]["homed_axes"] == "xyz"
    assert status["toolhead"]["position"][:3] == [0.0, 0.0, 0.0]
    await client.gcode_script("M118 hello-from-kybercore")
    console = await client.gcode_store(count=20)
    messages = [entry["message"] for entry in console]
    assert "G28" in messages
    assert any("hello-from-kybercore" in message for message in messages)


async def test_file_upload_list_metadata_download_delete(client: MoonrakerClient) -> None:
    name = f"kc-{uuid.uuid4().hex[:6]}.gcode"
    content = travel_gcode(moves=4)
    result = await client.upload(name, content)
    assert result["item"]["path"] == name
    assert result["print_started"] is False
    assert name in [f["path"] for f in await client.files_list()]
    meta = await client.file_metadata(name)
    assert meta["size"] == len(content)
    assert meta["estimated_time"] == pytest.approx(10, abs=1)
    assert await client.file_thumbnails(name) == []
    downloaded = await client.download(name)
    assert hashlib.sha256(downloaded).digest() == hashlib.sha256(content).digest()
    await client.delete_file(name)
    assert name not in [f["path"] for f in await client.files_list()]
    with pytest.raises(MoonrakerRpcError) as missing:
        await client.file_metadata("never-uploaded.gcode")
    assert missing.value.rpc_code == 404


async def test_print_start_pause_resume_cancel_and_history(client: MoonrakerClient) -> None:
    name = f"kc-print-{uuid.uuid4().hex[:6]}.gcode"
    await client.upload(name, travel_gcode(moves=40))
    await client.print_start(name)
    await wait_print_state(client, "printing")
    await client.print_pause()
    await wait_print_state(client, "paused")
    await client.print_resume()
    await wait_print_state(client, "printing")
    await client.print_cancel()
    await wait_print_state(client, "cancelled")
    history = await client.history_list(limit=5)
    assert history["jobs"][0]["filename"] == name
    assert history["jobs"][0]["status"] == "cancelled"
    totals = await client.history_totals()
    assert totals["job_totals"]["total_jobs"] >= 1
    await client.delete_file(name)


async def test_upload_and_print_at_once(client: MoonrakerClient) -> None:
    name = f"kc-direct-{uuid.uuid4().hex[:6]}.gcode"
    result = await client.upload(name, travel_gcode(moves=20), start=True)
    assert result["print_started"] is True
    await wait_print_state(client, "printing")
    await client.print_cancel()
    await wait_print_state(client, "cancelled")
    await client.delete_file(name)


async def test_webcams_list_names_the_virtual_printers_webcam(client: MoonrakerClient) -> None:
    (webcam,) = await client.webcams_list()
    assert webcam["name"] == "kybercam"
    assert webcam["snapshot_url"].startswith("http://127.0.0.1:")


async def test_emergency_stop_firmware_restart_and_restart(
    own_printer: PrinterStack, http: httpx.AsyncClient
) -> None:
    client = MoonrakerClient(own_printer.url, http, name="own")
    # A session of its own reports every change of Klippy's state, however short.
    seen: list[str] = []
    watcher = MoonrakerClient(
        own_printer.url,
        http,
        name="own-watcher",
        on_event=lambda e: seen.append(e.state) if isinstance(e, KlippyChanged) else None,
    )
    watcher.start()
    try:
        await client.emergency_stop()

        async def klippy_state() -> str:
            try:
                return str((await client.server_info())["klippy_state"])
            except MoonrakerRpcError:
                return "unknown"

        states: list[str] = []

        async def wait_state(wanted: str) -> None:
            for _ in range(200):
                states.append(await klippy_state())
                if states[-1] == wanted:
                    return
                await asyncio.sleep(0.05)  # poll: wait for the state, 200 tries
            raise AssertionError(f"Klippy never reached {wanted}: {states[-5:]}")

        await wait_state("shutdown")
        info = await client.printer_info()
        assert "shutdown" in info["state_message"].lower() or info["state"] == "shutdown"
        await client.firmware_restart()
        await wait_state("ready")
        # A restart that never happened must not pass: Klippy leaves ready, then comes back.
        await wait_for(lambda: seen[-1:] == ["ready"], what="the watcher to see Klippy ready")
        mark = len(seen)
        await client.restart()
        await wait_for(lambda: len(seen) > mark, what="Klippy to leave ready")
        await wait_for(lambda: seen[-1] == "ready", timeout=20, what="Klippy back at ready")
        await wait_state("ready")
    finally:
        await watcher.close()


async def test_wrong_api_key_is_auth_failed(printer: PrinterStack, http: httpx.AsyncClient) -> None:
    # Moonraker checks a key that is sent even from a trusted address.
    client = MoonrakerClient(printer.url, http, name="shared", api_key="not-the-key")
    with pytest.raises(PrinterAuthFailed, match="API key"):
        await client.server_info()
