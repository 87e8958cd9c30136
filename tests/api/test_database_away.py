"""The API while its database does not answer: what needs the database says so (503
``database_unavailable``, what to do), never an internal error with a traceback in the
log; the printers are driven as before, their actions' audit rows wait and are written
once the database answers, and everything answers again by itself. A real PostgreSQL,
reached through a :class:`~tests.cable.Cable` the test cuts and mends, and a real
printer."""

from __future__ import annotations

import logging
from collections.abc import Awaitable
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.api.app import create_app
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry, write_printers
from kybercore.sim.stack import PrinterStack
from tests.cable import to_database
from tests.helpers import wait_for

READY_WITHIN = 60.0
BACK_WITHIN = 30.0
"""A new connection once the line is mended; a busy machine is slower."""
TASKS = (
    "plan the queue",
    "check the queue for notifications",
    "read the queue's gates and depth",
)
"""The background tasks that read the database on their own."""
NEEDS_THE_DATABASE = ("/api/history", "/api/stats", "/api/jobs", "/api/queue", "/api/gates")


async def test_a_database_away_is_a_503_that_says_so_and_passes(
    postgres_database: str, printer: PrinterStack, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "printers.json"
    name = printer.options.name
    write_printers(path, [PrinterConfig(id=name, name=name, moonraker_url=printer.url)])
    cable, url = to_database(postgres_database)
    caplog.set_level(logging.INFO, logger="kybercore")
    app = create_app(PrinterRegistry(path), database_url=url, notify_options={"queue_poll": 0.1})
    try:
        async with (
            app.router.lifespan_context(app),
            httpx.AsyncClient(
                transport=httpx.ASGITransport(app), base_url="http://127.0.0.1", timeout=30
            ) as api,
        ):
            for route in NEEDS_THE_DATABASE:
                assert (await api.get(route)).status_code == 200, route
            await wait_for(lambda: ready(api, name), READY_WITHIN, "the printer ready")
            cable.cut()
            for route in NEEDS_THE_DATABASE:
                away = await api.get(route)
                assert away.status_code == 503, (route, away.text)
                error = away.json()["error"]
                assert error["code"] == "database_unavailable", route
                assert "does not answer" in error["message"]
                assert "try again" in error["message"]
            # The fleet itself does not need the database: its printers are driven, and
            # the action's audit row waits.
            assert (await api.get("/api/printers")).status_code == 200
            sent = await api.post(f"/api/printers/{name}/gcode", json={"script": "M115"})
            assert sent.status_code == 200, sent.text
            assert any("FIRMWARE_NAME" in line for line in sent.json()["response"])
            assert said(caplog, "The audit row of POST /api/printers/{printer_id}/gcode waits")
            # Nor do the background tasks stop: each says the outage once, then again once
            # it is over.
            app.state.queue.dispatcher.wake()
            await wait_for(lambda: all(said(caplog, f"cannot {t} (") for t in TASKS),
                           BACK_WITHIN, "each background task to meet the outage")  # fmt: skip
            cable.mend()

            async def answers() -> bool:
                return all([(await api.get(r)).status_code == 200 for r in NEEDS_THE_DATABASE])

            await wait_for(answers, BACK_WITHIN, "every route to answer again")
            await wait_for(lambda: all(said(caplog, f"can {t} again") for t in TASKS),
                           BACK_WITHIN, "each background task back at work")  # fmt: skip

            async def audited() -> list[tuple[str, str, str]]:
                rows = (await api.get("/api/audit")).json()["items"]
                return [(r["action"], r["target"], r["outcome"]) for r in rows]

            await wait_for(lambda: _has(audited(), ("printer.gcode", f"printer:{name}", "ok")),
                           BACK_WITHIN, "the audit row written")  # fmt: skip
    finally:
        cable.close()
    unexpected = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert unexpected == [], "a database away is not an error of KyberCore's"
    assert [r.getMessage() for r in caplog.records if r.exc_info] == []


def said(caplog: pytest.LogCaptureFixture, words: str) -> bool:
    return any(words in r.getMessage() for r in caplog.records)


async def ready(api: httpx.AsyncClient, printer_id: str) -> bool:
    view = (await api.get(f"/api/printers/{printer_id}")).json()
    return bool(view["connection"] == "online" and view["klippy_state"] == "ready")


async def _has(read: Awaitable[list[Any]], row: Any) -> bool:
    return row in await read
