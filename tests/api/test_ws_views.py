"""``/ws`` with a view: a real ``kybercore serve`` over real Moonraker + Klippy printers, one
browser showing every printer and one showing a single tile."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import websockets

from kybercore.registry.store import write_printers
from kybercore.sim.stack import free_port
from tests.browser_mirror import BrowserMirror
from tests.helpers import KyberCoreServer

pytestmark = pytest.mark.integration

FLEET = ("fleet-a", "fleet-b", "fleet-c")


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


def views_frames(mirror: BrowserMirror) -> list[dict[str, Any]]:
    return mirror.events("views")


async def test_a_browser_gets_full_views_of_its_tiles_and_summaries_of_the_rest(
    kybercore_server: KyberCoreServer, api: httpx.AsyncClient
) -> None:
    url = kybercore_server.ws_url
    async with BrowserMirror(url) as everything, BrowserMirror(url) as paged:
        await everything.wait(
            lambda: all(everything.printers[p]["klippy_state"] == "ready" for p in FLEET),
            what="fleet ready",
        )
        # From "everything" to nothing, then to one tile: that tile's full view comes back,
        # which also tells the test that the server applied the view.
        await paged.send({"type": "view", "printers": []})
        await paged.send({"type": "view", "printers": ["fleet-a"]})
        await paged.wait(lambda: len(views_frames(paged)) == 1, what="fleet-a's full view")
        [entered] = views_frames(paged)[0]["printers"]
        assert entered["id"] == "fleet-a"
        assert "extruder" in entered
        since = len(paged.frames)
        try:
            for printer, target in (("fleet-b", 40), ("fleet-a", 41)):
                answer = await api.post(
                    f"/api/printers/{printer}/gcode", json={"script": f"M104 S{target}"}
                )
                assert answer.status_code == 200, answer.text
                await everything.wait(
                    lambda p=printer, t=target: everything.printers[p]["extruder"]["target"] == t,
                    what=f"{printer} target {target} (everything)",
                )
            # In view: followed in full. Out of view: the summary only, which has no heaters.
            await paged.wait(
                lambda: paged.printers["fleet-a"]["extruder"]["target"] == 41,
                what="fleet-a target 41 (one tile)",
            )
            assert paged.printers["fleet-b"]["extruder"]["target"] != 40
            deltas = [f for f in paged.frames[since:] if f["type"] == "delta"]
            assert deltas
            assert all("fleet-b" not in f["full"] for f in deltas)
            assert all("extruder" not in patch for f in deltas for patch in f["printers"].values())
            for printer in FLEET:  # what the dashboard sorts and counts by, for every printer
                summary = paged.printers[printer]
                assert summary["connection"] == "online"
                assert summary["job"]["state"] in ("standby", "complete", "cancelled", "")
                assert summary["name"]

            # fleet-b scrolls into view: its full view comes at once, not with its next change.
            await paged.send({"type": "view", "printers": ["fleet-a", "fleet-b"]})
            await paged.wait(lambda: len(views_frames(paged)) == 2, what="fleet-b's full view")
            [view] = views_frames(paged)[1]["printers"]
            assert view["id"] == "fleet-b"
            assert view["extruder"]["target"] == 40
            assert paged.printers["fleet-b"]["extruder"]["target"] == 40
        finally:
            for printer in ("fleet-a", "fleet-b"):
                await api.post(f"/api/printers/{printer}/gcode", json={"script": "M104 S0"})


async def test_a_browser_naming_its_view_in_the_url_gets_that_views_snapshot_first(
    kybercore_server: KyberCoreServer,
) -> None:
    # As the dashboard reconnects: its first snapshot is already the view's, not the fleet in
    # full; an id the fleet does not have is ignored.
    async with BrowserMirror(f"{kybercore_server.ws_url}?view=fleet-a,nobody") as paged:
        snapshot = next(f for f in paged.frames if f["type"] == "snapshot")
    assert [view["id"] for view in snapshot["full"]] == ["fleet-a"]
    assert "extruder" in snapshot["full"][0]
    assert {summary["id"] for summary in snapshot["printers"]} >= set(FLEET)
    assert all("extruder" not in summary for summary in snapshot["printers"])


async def test_frames_go_out_uncompressed_to_a_browser_offering_deflate(
    kybercore_server: KyberCoreServer,
) -> None:
    # Every browser offers permessage-deflate; compressing each frame once per browser cost
    # 13-15 % more CPU per event (bench/ingest_cost.py --deflate). Moonraker does not either.
    async with websockets.connect(kybercore_server.ws_url, proxy=None) as ws:
        assert ws.protocol.extensions == []
        assert b'"type":"snapshot"' in await ws.recv(decode=False)


@pytest.mark.parametrize("command", ["serve", "front"])
async def test_ws_compress_deflates_frames_for_a_browser_offering_it(
    tmp_path: Path, command: str, request: pytest.FixtureRequest
) -> None:
    # For a dashboard watched over a slow link: the bytes matter more than the CPU.
    write_printers(tmp_path / "printers.json", [])
    broker = ("--nats", request.getfixturevalue("nats_server").url) if command == "front" else ()
    server = KyberCoreServer(
        tmp_path / "printers.json", free_port(), "--ws-compress", *broker, command=command
    )
    try:
        await asyncio.to_thread(server.start)  # it blocks
        async with websockets.connect(server.ws_url, proxy=None) as ws:
            assert [e.name for e in ws.protocol.extensions] == ["permessage-deflate"]
            assert b'"type":"snapshot"' in await ws.recv(decode=False)
    finally:
        await asyncio.to_thread(server.stop)
