"""The queue's printers on a front, without a broker: what a view shows the queue, which
patches are which changes, and a FrontFleet's views fed by hand as its workers would."""

from __future__ import annotations

import dataclasses
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from nats.errors import ConnectionClosedError

from kybercore.core.view import LivePrinter, facts, fuse
from kybercore.errors import OutcomeUnknown, PrinterUnreachable, UnknownPrinter
from kybercore.jobs.printers import Change, QueuePrinters, heat_of, shown_of
from kybercore.jobs.tracker import from_history, seen
from kybercore.registry.models import PrinterConfig
from kybercore.scale.front import FrontFleet
from kybercore.scale.queue import FrontPrinters, changes_of, heaters_of, shown_of_view
from kybercore.scale.slots import SlotRef, slot_of

NO_WORKER = "No KyberCore worker has reported this printer yet: is `kybercore ingest` running?"
SLOTS = 4
PRINTING: dict[str, Any] = {
    "webhooks": {"state": "ready", "state_message": "Printer is ready"},
    "print_stats": {
        "state": "printing",
        "filename": "kybercore/j1-a.gcode",
        "print_duration": 61.0,
        "message": "",
    },
    "extruder": {"temperature": 150.0, "target": 210.0},
    "heater_bed": {"temperature": 60.0, "target": 60.0},
    "toolhead": {"axis_minimum": [0.0, -3.0, 0.0, 0.0]},
}


def config(printer_id: str) -> PrinterConfig:
    return PrinterConfig(id=printer_id, name=printer_id.upper(), moonraker_url="http://h:7125")


def online(**changes: Any) -> LivePrinter:
    # As a session keeps it: Klippy's message is webhooks' state_message.
    live = LivePrinter(
        connection="online", klippy_state="ready", klippy_message="Printer is ready",
        status=PRINTING, limits="known",
    )  # fmt: skip
    return dataclasses.replace(live, **changes)


@pytest.mark.parametrize(
    ("patch", "changes"),
    [
        (None, ["state"]),
        ({"job": {"state": "complete", "progress": 1.0}}, ["state"]),
        ({"job": {"filename": "b.gcode"}}, ["state"]),
        ({"connection": "offline", "connection_error": "refused"}, ["state"]),
        ({"klippy_state": "shutdown", "klippy_message": "MCU shutdown"}, ["state"]),
        ({"extruder": {"temperature": 180.0}}, ["heaters"]),
        ({"bed": {"target": 0.0}, "job": {"progress": 0.5}}, ["heaters"]),
        ({"spool": {"remaining_g": 80.0}}, ["spool"]),
        ({"spoolman": "unreachable"}, ["spool"]),
        (
            {"job": {"state": "printing"}, "extruder": {"target": 200.0}, "spool": None},
            ["state", "heaters", "spool"],
        ),
        ({"job": {"progress": 0.51, "eta_seconds": 40}, "updated_at": 12.5}, []),
        ({"toolhead": {"position": [1, 2, 3, 4]}, "fan_speed": 0.5}, []),
    ],
)
def test_a_patch_is_the_changes_the_queue_hears_of(
    patch: dict[str, Any] | None, changes: list[Change]
) -> None:
    assert changes_of(patch) == changes


@pytest.mark.parametrize(
    "live",
    [
        online(),
        online(status={**PRINTING, "extruder": {"temperature": 207.0, "target": 210.0}}),
        online(status={**PRINTING, "extruder": {"target": 0.0}, "heater_bed": {"target": 0.0}}),
        online(
            status={
                **PRINTING,
                "print_stats": {
                    "state": "cancelled",
                    "filename": "a.gcode",
                    "message": "Cancelled by user",
                    "print_duration": 12.0,
                },
            }
        ),
        LivePrinter(connection="offline"),
        LivePrinter(),
    ],
)
def test_a_view_shows_what_the_live_state_shows(live: LivePrinter) -> None:
    expected = shown_of(live)
    if expected.print_duration is None:  # no status yet: the view says 0 (see below)
        expected = dataclasses.replace(expected, print_duration=0.0)
    assert shown_of_view(fuse(config("p"), live)) == expected
    assert heat_of(heaters_of(fuse(config("p"), live))) == heat_of(live.status)


def test_what_a_view_shows_differs_where_the_view_says_less() -> None:
    # Klippy down mid-print: the view blanks the job's state (the tracker then asks the
    # history how it ended).
    why = "MCU 'mcu' shutdown: Timer too close"
    webhooks = {"state": "shutdown", "state_message": why}
    down = online(klippy_state="shutdown", klippy_message=why,
                  status={**PRINTING, "webhooks": webhooks})  # fmt: skip
    shown = shown_of_view(fuse(config("p"), down))
    assert (shown.state, shown.klippy_message) == ("", why)
    assert dataclasses.replace(shown, state="printing") == shown_of(down)
    # The duration is in whole seconds, 0 before any print.
    stats = {"state": "standby", "filename": "", "print_duration": 61.4}
    idle = online(status={**PRINTING, "print_stats": stats})
    assert (
        shown_of_view(fuse(config("p"), idle)).print_duration,
        shown_of(idle).print_duration,
    ) == (61.0, 61.4)
    fresh = online(status={**PRINTING, "print_stats": {"state": "standby"}})
    assert (
        shown_of_view(fuse(config("p"), fresh)).print_duration,
        shown_of(fresh).print_duration,
    ) == (0.0, None)


def test_a_shutdown_mid_print_is_recorded_in_the_same_words_on_a_front_as_on_serve() -> None:
    why = "MCU 'mcu' shutdown: Timer too close\nOnce the underlying issue is corrected, ..."
    webhooks = {"state": "shutdown", "state_message": why}
    down = online(klippy_state="shutdown", klippy_message=why,
                  status={**PRINTING, "webhooks": webhooks})  # fmt: skip
    name = PRINTING["print_stats"]["filename"]
    on_serve = seen(shown_of(down), name)
    assert on_serve is not None
    # A front's view blanks the print's state: only the history says the print was cut short.
    on_front = shown_of_view(fuse(config("p"), down))
    assert seen(on_front, name) is None
    history = {"filename": name, "status": "klippy_shutdown", "print_duration": 61.0}
    assert from_history(history, on_front) == on_serve
    assert on_serve.reason == "Klipper shut down mid-print: MCU 'mcu' shutdown: Timer too close"
    # Without Klippy still shut down under that file, the history's own words.
    ready = shown_of_view(fuse(config("p"), online()))
    said = from_history(history, ready).reason
    assert said == "Klipper shut down mid-print (Moonraker's history)."


@pytest.fixture
async def fleet(tmp_path: Path) -> AsyncIterator[FrontFleet]:
    """A front not connected to any broker: its views are fed by hand."""
    async with httpx.AsyncClient() as http:
        front = FrontFleet("nats://127.0.0.1:1", http, slots=SLOTS, printers_file=tmp_path / "p")
        front._on_printers([config("p1"), config("p2")])
        yield front


def snapshot(fleet: FrontFleet, printer_id: str, live: LivePrinter, now: float = 0.0) -> SlotRef:
    """The view of ``live`` from the printer's owner, as a snapshot of its slot."""
    slot = SlotRef("", slot_of(printer_id, SLOTS))
    view = fuse(config(printer_id), live)
    fleet.copy.snapshot(slot, {"epoch": 1, "seq": 1, "views": {printer_id: view}}, now)
    fleet.copy.check(now)  # fresh
    return slot


async def test_every_printer_is_planned_from_its_view(fleet: FrontFleet) -> None:
    printers: QueuePrinters = FrontPrinters(fleet)
    snapshot(fleet, "p1", online())
    found = {p.config.id: p for p in printers.all()}
    assert set(found) == {"p1", "p2"}
    assert found["p1"].facts == facts(config("p1"), online())
    assert found["p1"].heating is True  # 150 °C of 210
    # Nobody has reported p2: connecting, so the planner starts nothing there.
    assert (found["p2"].facts.connection, found["p2"].heating) == ("connecting", False)
    assert printers.shown("p1").filename == "kybercore/j1-a.gcode"
    with pytest.raises(UnknownPrinter):
        printers.shown("p3")


async def test_a_silent_owners_printers_are_stale(fleet: FrontFleet) -> None:
    printers = FrontPrinters(fleet)
    snapshot(fleet, "p1", online())
    heard: list[tuple[str, Change]] = []
    printers.listen(lambda printer_id, change: heard.append((printer_id, change)))
    fleet.copy.check(1000.0)
    assert printers.shown("p1").connection == "stale"
    assert next(p for p in printers.all() if p.config.id == "p1").facts.connection == "stale"
    assert ("p1", "state") in heard


async def test_patches_and_snapshots_reach_the_listeners_until_they_stop(
    fleet: FrontFleet,
) -> None:
    printers = FrontPrinters(fleet)
    slot = snapshot(fleet, "p1", online())
    heard: list[tuple[str, Change]] = []
    stop = printers.listen(lambda printer_id, change: heard.append((printer_id, change)))
    patch = {"job": {"state": "complete"}, "extruder": {"target": 0.0}}
    batch = {"epoch": 1, "seq": 2, "removed": [], "events": [], "patches": {"p1": patch}}
    fleet.copy.batch(slot, batch, 0.5)
    assert heard == [("p1", "state"), ("p1", "heaters")]
    assert printers.shown("p1").state == "complete"
    heard.clear()
    fleet._on_printers([config("p1")])  # p2 removed from the registry
    assert sorted(heard) == [("p1", "state"), ("p2", "state")]
    stop()
    heard.clear()
    snapshot(fleet, "p1", online(), now=1.0)
    assert heard == []


async def test_one_failing_watcher_does_not_stop_the_others(fleet: FrontFleet) -> None:
    heard: list[str] = []

    def broken(printer_id: str, patch: dict[str, Any] | None) -> None:
        raise RuntimeError("bug")

    fleet.watch(broken)
    fleet.watch(lambda printer_id, patch: heard.append(printer_id))
    snapshot(fleet, "p1", online())
    assert heard
    assert set(heard) == {"p1"}


async def test_a_start_whose_outcome_is_unknown_is_printer_unreachable(
    fleet: FrontFleet, monkeypatch: pytest.MonkeyPatch
) -> None:
    printers = FrontPrinters(fleet)
    failures: list[Exception] = [
        OutcomeUnknown("the worker did not answer", printer="p1"),
        ConnectionClosedError(),
    ]

    async def command(printer_id: str, op: str, **args: Any) -> Any:
        raise failures.pop(0)

    monkeypatch.setattr(fleet, "command", command)
    for _ in range(2):
        with pytest.raises(PrinterUnreachable):
            await printers.start("p1", "kybercore/j1-a.gcode")


async def test_an_unreported_printers_view_is_made_once_per_configuration(
    fleet: FrontFleet,
) -> None:
    # The queue and the notifications read every printer each round: at 5,000 printers
    # coming online, fusing each unreported one at every read took a third of a core.
    unheard = LivePrinter(connection_error=NO_WORKER)
    first = fleet.current_view("p2")
    assert first == fuse(config("p2"), unheard)
    assert fleet.current_view("p2") is first
    renamed = config("p2").model_copy(update={"name": "Renamed"})
    fleet._on_printers([config("p1"), renamed])
    assert fleet.current_view("p2") == fuse(renamed, unheard)
    assert fleet.current_view("p2")["name"] == "Renamed"


async def test_an_unreported_printer_of_a_site_says_which_workers_to_start(
    fleet: FrontFleet,
) -> None:
    far = config("p3").model_copy(update={"site": "lab-b"})
    fleet._on_printers([config("p1"), far])
    view = fleet.current_view("p3")
    assert view["connection"] == "connecting"
    assert "`kybercore ingest --site lab-b`" in view["connection_error"]
    # Its slot is its site's: the default site's same slot being heard does not count.
    assert slot_of("p3", SLOTS) == slot_of("p1", SLOTS)
    snapshot(fleet, "p1", online())
    assert fleet.reported("p1")
    assert not fleet.reported("p3")
