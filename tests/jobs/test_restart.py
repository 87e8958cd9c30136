"""KyberCore killed (SIGKILL) with a copy printing, a plate awaiting its clear and a start
not yet confirmed; started again on the same data folder, it picks up where it was.

A real ``kybercore serve`` process over real Moonraker + Klippy printers, driven through
its HTTP API. The start that is never confirmed goes to a printer behind a
FAULT-INJECTION stand-in that answers starts "ok" and drops them
(:mod:`tests.jobs.start_faults`), so KyberCore is surely killed while it waits.
"""

from __future__ import annotations

import asyncio
import os
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.jobs.tracker import RESTARTED
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.sim.stack import PrinterStack, free_port
from tests.helpers import KyberCoreServer, travel_gcode, wait_for
from tests.jobs.start_faults import StartFaultProxy

pytestmark = pytest.mark.integration

PRINT_WITHIN = 120.0
"""A dispatch round, an upload, a verified start and a travel print of 5-40 s, with slack."""


@pytest.fixture(scope="module")
def restart_printers(start_stack: Callable[..., PrinterStack]) -> dict[str, PrinterStack]:
    """One printer for a long print, one for short ones, two behind stand-ins."""
    return {name: start_stack(f"q-{name}") for name in ("long", "short", "unsure", "late")}


@pytest.mark.timeout(600)
async def test_a_kill_mid_print_and_mid_start_is_settled_and_the_gate_holds(
    restart_printers: dict[str, PrinterStack], tmp_path: Path
) -> None:
    proxy = StartFaultProxy(restart_printers["unsure"].url, "swallow_start")
    await proxy.start()
    late_proxy = StartFaultProxy(restart_printers["late"].url, "held_start")
    await late_proxy.start()
    urls = {
        "long": restart_printers["long"].url,
        "short": restart_printers["short"].url,
        "unsure": proxy.url,
        "late": late_proxy.url,
    }
    write_printers(
        tmp_path / "printers.json",
        [PrinterConfig(id=name, name=name, moonraker_url=url) for name, url in urls.items()],
    )
    server = KyberCoreServer(tmp_path / "printers.json", free_port())
    try:
        # In threads: they block, and the stand-in serves from this event loop.
        await asyncio.to_thread(server.start)
        await asyncio.to_thread(server.wait_online, 4)
        async with httpx.AsyncClient(base_url=server.url, timeout=60) as api:
            short = await add_job(api, "short.gcode", travel_gcode(moves=4, feedrate=6000),
                                  printer="short", quantity=2)  # fmt: skip
            await wait_for(lambda: gate_is(api, "short", "awaiting_clear"), PRINT_WITHIN,
                           "the first short copy ended, its plate awaiting a clear")  # fmt: skip
            long = await add_job(api, "long.gcode", travel_gcode(moves=16, feedrate=3000),
                                 printer="long")  # fmt: skip
            unsure = await add_job(api, "unsure.gcode", travel_gcode(moves=4, feedrate=6000),
                                   printer="unsure")  # fmt: skip
            await wait_for(lambda: attempt_is(api, long["id"], "printing"), PRINT_WITHIN,
                           "the long copy printing")  # fmt: skip
            await wait_for(lambda: attempt_is(api, unsure["id"], "starting"), PRINT_WITHIN,
                           "the unsure copy waiting for its start")  # fmt: skip
            assert proxy.starts_swallowed
            late = await add_job(api, "late.gcode", travel_gcode(moves=4, feedrate=6000),
                                 printer="late")  # fmt: skip
            await wait_for(lambda: bool(late_proxy.starts_held), PRINT_WITHIN, "a start sent")
            assert await attempt_is(api, late["id"], "starting")
            printing = (await attempts(api, long["id"]))[0]
            # Still printing when KyberCore dies (the print lasts ~20 s).
            stats = await print_stats(restart_printers["long"])
            assert (stats["state"], stats["filename"]) == ("printing", printing["upload_name"])

            os.kill(server.pid, signal.SIGKILL)
            await asyncio.to_thread(server.stop)  # reaps it
            # The start KyberCore sent reaches the printer only now: it prints while
            # KyberCore is dead.
            await late_proxy.release_starts()
            (late_name,) = late_proxy.starts_held
            await wait_for(
                lambda: printing_file(restart_printers["late"], late_name),
                PRINT_WITHIN,
                "the late start printing",
            )

            # The same printers.json, the same database beside it.
            await asyncio.to_thread(server.start)
            # The long copy is followed to its real end, whenever that came.
            await wait_for(lambda: attempt_is(api, long["id"], "completed"), PRINT_WITHIN,
                           "the long copy completed")  # fmt: skip
            ended = (await attempts(api, long["id"]))[0]
            assert ended["id"] == printing["id"]
            assert ended["moonraker_job_id"]
            # The start sent before the kill is found printing, and followed to its end.
            await wait_for(lambda: attempt_is(api, late["id"], "completed"), PRINT_WITHIN,
                           "the late copy completed")  # fmt: skip
            (late_attempt,) = await attempts(api, late["id"])
            assert late_attempt["upload_name"] == late_name
            # The start nobody saw is settled from the printer: it never printed.
            await wait_for(lambda: attempt_is(api, unsure["id"], "failed_to_start"),
                           PRINT_WITHIN, "the unsure start settled")  # fmt: skip
            (never,) = await attempts(api, unsure["id"])
            assert never["reason"] == RESTARTED
            gates = (await api.get("/api/gates")).json()
            assert gates["unsure"]["state"] == "held"
            assert RESTARTED in gates["unsure"]["reason"]
            # The plate that awaited a clear still does: its second copy waits.
            assert gates["short"]["state"] == "awaiting_clear"
            assert len(await attempts(api, short["id"])) == 1
            why = (await api.get(f"/api/jobs/{short['id']}/why")).json()
            assert any(
                line["subject"] == "short" and line["code"] == "awaiting_clear" for line in why
            ), why

            cleared = await api.post("/api/printers/short/clear", json={"verdict": "good"})
            assert cleared.status_code == 200, cleared.text
            await wait_for(
                lambda: attempt_is(api, short["id"], "completed", nth=2),
                PRINT_WITHIN,
                "the second short copy printed after the clear",
            )
            await api.post("/api/printers/short/clear", json={"verdict": "good"})
            done = (await api.get(f"/api/jobs/{short['id']}")).json()
            assert (done["state"], done["done"]) == ("done", 2)
    finally:
        await asyncio.to_thread(server.stop)
        await late_proxy.stop()
        await proxy.stop()


async def add_job(api: httpx.AsyncClient, name: str, content: bytes, **fields: Any) -> Any:
    """Queue ``content`` as a job through the API; its JSON."""
    answer = await api.post(
        "/api/jobs",
        files={"file": (name, content)},
        data={k: str(v) for k, v in fields.items()},
    )
    assert answer.status_code == 201, answer.text
    return answer.json()


async def attempts(api: httpx.AsyncClient, job_id: int) -> list[dict[str, Any]]:
    """The job's attempts, oldest first."""
    answer = await api.get(f"/api/jobs/{job_id}/attempts")
    answer.raise_for_status()
    return sorted(answer.json(), key=lambda a: a["id"])


async def attempt_is(api: httpx.AsyncClient, job_id: int, state: str, nth: int = 1) -> bool:
    """Whether the job has ``nth`` attempts and the last is in ``state``."""
    found = await attempts(api, job_id)
    return len(found) == nth and found[-1]["state"] == state


async def gate_is(api: httpx.AsyncClient, printer: str, state: str) -> bool:
    gates = (await api.get("/api/gates")).json()
    return bool(gates.get(printer, {}).get("state") == state)


async def print_stats(stack: PrinterStack) -> dict[str, Any]:
    """``print_stats`` asked of the printer's Moonraker directly."""
    async with httpx.AsyncClient(timeout=10) as moonraker:
        answer = await moonraker.get(f"{stack.url}/printer/objects/query?print_stats")
        stats: dict[str, Any] = answer.json()["result"]["status"]["print_stats"]
        return stats


async def printing_file(stack: PrinterStack, filename: str) -> bool:
    """Whether the printer prints (or printed) ``filename`` now."""
    stats = await print_stats(stack)
    return bool(stats["filename"] == filename and stats["state"] in ("printing", "complete"))
