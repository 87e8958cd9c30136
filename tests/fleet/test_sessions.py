"""Sessions kept in step with the printers' configuration: only what changed is rendered
and sent (a worker applies its share of the fleet whenever its slots or the registry move)."""

from __future__ import annotations

import httpx

from kybercore.fleet.hub import Hub
from kybercore.fleet.sessions import Sessions
from kybercore.registry.models import PrinterConfig


def printer(printer_id: str, name: str = "") -> PrinterConfig:
    # Disabled: no session is opened, only the configuration is applied.
    port = 1 + ord(printer_id[0])  # each its own address: printers.json's rule
    return PrinterConfig(
        id=printer_id, name=name or printer_id.upper(), moonraker_url=f"http://127.0.0.1:{port}",
        enabled=False,
    )  # fmt: skip


async def test_applying_the_same_fleet_again_renders_nothing() -> None:
    rendered: list[str] = []
    async with httpx.AsyncClient() as http:

        def render(printer_id: str) -> dict[str, str]:
            rendered.append(printer_id)
            return {"id": printer_id}

        hub = Hub(render)
        sessions = Sessions(http, connect=None, hub=hub)  # type: ignore[arg-type]
        await sessions.apply([printer("a"), printer("b"), printer("c")])
        assert sorted(rendered) == ["a", "b", "c"]

        rendered.clear()
        await sessions.apply([printer("a"), printer("b"), printer("c")])
        assert rendered == []

        await sessions.apply([printer("a"), printer("b", "Renamed")])
        assert sorted(rendered) == ["b", "c"]  # b edited, c removed
        assert sessions.get("b").config.name == "Renamed"
        await sessions.close()
