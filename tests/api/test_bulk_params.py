"""A bulk action's ``printer_ids`` say which printers, never what to do on each: they are
not among the parameters each printer's action, its rules and the advisor receive."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest
from pydantic import SecretStr

from kybercore.api.app import create_app
from kybercore.api.models import FleetActionRequest
from kybercore.fleet.advisor import AdvisorConfig
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry, write_printers
from kybercore.sim.stack import PrinterStack
from tests.fleet.test_advisor import FakeChatCompletionsServer
from tests.helpers import wait_for


def test_the_printer_ids_are_not_a_parameter_of_the_action() -> None:
    request = FleetActionRequest(printer_ids=["a", "b"], extruder=40, confirm=True)
    assert request.params() == {"extruder": 40}


@pytest.fixture
async def advised_api(
    own_printer: PrinterStack, tmp_path: Path
) -> AsyncIterator[tuple[httpx.AsyncClient, FakeChatCompletionsServer]]:
    """The app in this process with one real printer and the advisor stand-in (not a model).

    A printer of its own: the test heats it, and the shared fleet printers must stay at room
    temperature for the tests that read them."""
    path = tmp_path / "printers.json"
    write_printers(path, [PrinterConfig(id="b", name="B", moonraker_url=own_printer.url)])
    async with FakeChatCompletionsServer(mode="warnings") as advisor:
        config = AdvisorConfig(advisor.url, SecretStr("advisor-key"), budget_seconds=5.0)
        app = create_app(PrinterRegistry(path), advisor=config)
        async with (
            app.router.lifespan_context(app),
            httpx.AsyncClient(
                transport=httpx.ASGITransport(app), base_url="http://127.0.0.1", timeout=30
            ) as api,
        ):

            async def ready() -> bool:
                view = (await api.get("/api/printers/b")).json()
                return bool(view["klippy_state"] == "ready" and view["limits"] == "known")

            # Limits too: a temperature is checked against them, and on a busy machine their
            # read can still be under way (``limits_loading``) when Klippy is shown ready.
            await wait_for(ready, what="printer ready, its limits read")
            yield api, advisor


@pytest.mark.integration
async def test_a_bulk_action_sends_no_printer_ids_to_the_advisor(
    advised_api: tuple[httpx.AsyncClient, FakeChatCompletionsServer],
) -> None:
    api, advisor = advised_api
    body = {"printer_ids": ["b"], "extruder": 30, "confirm": True}
    try:
        answer = await api.post("/api/fleet/actions/set_temperature", json=body)
        assert answer.status_code == 200, answer.text
        assert answer.json()["results"][0]["ok"], answer.text
        asked = [str(r.body) for r in advisor.requests]
        assert asked
        assert all("printer_ids" not in text for text in asked), asked
    finally:
        await api.post("/api/printers/b/actions/set_temperature", json={"extruder": 0})
