"""Listeners hear only the status deltas they declared an interest in; every other event
(connection, Klippy, snapshots, notifications) reaches every listener as before."""

from __future__ import annotations

import httpx

from kybercore.fleet.hub import Hub
from kybercore.fleet.sessions import FleetPrinter, Interest, Sessions
from kybercore.jobs import printers
from kybercore.ledger import service as ledger
from kybercore.moonraker.events import (
    ConnectionChanged,
    Notification,
    SessionEvent,
    StatusDelta,
    StatusSnapshot,
)
from kybercore.notify import printers as notify
from kybercore.registry.models import PrinterConfig

TEMPERATURES = {"extruder": {"temperature": 210.3}, "heater_bed": {"temperature": 60.1}}
PROGRESS = {"print_stats": {"print_duration": 12.0, "filament_used": 3.1}}
STATE = {"print_stats": {"state": "paused"}}


def test_an_interest_wants_its_objects_fields_and_prefixes() -> None:
    interest = Interest(
        {"print_stats": frozenset({"state"}), "webhooks": None}, prefixes=("sensor ",)
    )
    assert interest.wants(STATE)
    assert interest.wants({**PROGRESS, "webhooks": {"state_message": "x"}})
    assert interest.wants({"sensor runout": {"filament_detected": False}})
    assert not interest.wants(PROGRESS)
    assert not interest.wants(TEMPERATURES)
    assert not interest.wants({})


def test_the_services_interests_pass_what_they_read_and_skip_the_rest() -> None:
    # Notifications: print states, files, messages, layers, Klippy, filament sensors.
    assert notify.INTEREST.wants(STATE)
    assert notify.INTEREST.wants({"print_stats": {"info": {"current_layer": 2}}})
    assert notify.INTEREST.wants({"print_stats": {"message": "oops"}})
    assert notify.INTEREST.wants({"filament_switch_sensor runout": {"filament_detected": False}})
    assert not notify.INTEREST.wants({**PROGRESS, **TEMPERATURES})
    # The ledger: print states only.
    assert ledger._INTEREST.wants(STATE)
    assert not ledger._INTEREST.wants({**PROGRESS, "webhooks": {"state": "ready"}})
    # The queue (dispatcher and tracker): print states, files, Klippy, and heaters (a start
    # seen, the heating budget); never progress alone.
    assert printers._INTEREST.wants({"print_stats": {"filename": "a.gcode"}})
    assert printers._INTEREST.wants({"webhooks": {"state": "shutdown"}})
    assert printers._INTEREST.wants({"extruder": {"temperature": 1.0}})
    assert not printers._INTEREST.wants(PROGRESS)
    assert not printers._INTEREST.wants({"toolhead": {"position": [0, 0, 0, 0]}})


async def test_sessions_skip_a_listener_for_deltas_outside_its_interest() -> None:
    async with httpx.AsyncClient() as http:
        hub = Hub(lambda _: None)
        sessions = Sessions(http, connect=None, hub=hub)  # type: ignore[arg-type]
        config = PrinterConfig(
            id="p1", name="P1", moonraker_url="http://127.0.0.1:1", enabled=False
        )
        printer = FleetPrinter(config, None)
        sessions._printers["p1"] = printer
        everything: list[SessionEvent] = []
        states: list[SessionEvent] = []
        sessions.listen(lambda _, event: everything.append(event))
        stop = sessions.listen(
            lambda _, event: states.append(event), Interest({"print_stats": frozenset({"state"})})
        )
        events: list[SessionEvent] = [
            StatusDelta(PROGRESS, 1.0),
            StatusDelta(STATE, 2.0),
            ConnectionChanged("online"),
            StatusSnapshot({"print_stats": {"state": "printing"}}),
            Notification("notify_gcode_response", ["ok"]),
        ]
        for event in events:
            sessions._on_event(printer, event)
        assert everything == events
        assert states == events[1:]
        # The live state took every delta in, whoever listened.
        assert printer.live.status["print_stats"]["state"] == "printing"
        stop()
        sessions._on_event(printer, StatusDelta(STATE, 3.0))
        assert len(states) == 4
        assert len(everything) == 6
