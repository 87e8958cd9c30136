"""Channel rules (filters, quiet hours) and the JSON of rules and events.

Each filter is shown on both sides: the event it lets through and the one it skips.
"""

from __future__ import annotations

from datetime import UTC, datetime, time, timedelta, timezone
from typing import Any

import pytest

from kybercore.notify.models import (
    DEFAULT_EVENTS,
    EVENT_KINDS,
    SEVERITY,
    EventKind,
    FleetEvent,
    PrinterRef,
)
from kybercore.notify.rules import ChannelRules, QuietHours, route
from kybercore.registry.models import PrinterConfig

T0 = datetime(2026, 5, 1, 22, 0, tzinfo=UTC)
P3 = PrinterRef("printer-3", "Printer 3", "Room B", ("pla", "big"))
NOON = time(12, 0)


def ev(
    kind: EventKind = "print_completed", who: PrinterRef | None = P3, **params: Any
) -> FleetEvent:
    return FleetEvent(kind, T0, who, params)


# --- the vocabulary ----------------------------------------------------------------------


def test_the_kinds_their_order_defaults_and_severities() -> None:
    assert EVENT_KINDS[0] == "print_started"
    assert EVENT_KINDS[-1] == "test"
    assert len(EVENT_KINDS) == len(set(EVENT_KINDS)) == 15
    assert set(EVENT_KINDS) - DEFAULT_EVENTS == {"first_layer_done", "test"}
    critical = {k for k, s in SEVERITY.items() if s == "critical"}
    warning = {k for k, s in SEVERITY.items() if s == "warning"}
    assert critical == {
        "print_failed", "printer_offline", "klippy_shutdown", "klippy_error", "storm_offline",
        "printer_unreported",
    }  # fmt: skip
    assert warning == {"print_paused", "plate_waiting", "job_blocked", "print_cancelled"}
    assert ev("print_started").severity == "info"


def test_a_printer_ref_of_a_configured_printer() -> None:
    config = PrinterConfig(
        id="printer-3", name="Printer 3", moonraker_url="http://127.0.0.1:7125", tags=["pla"]
    )
    assert PrinterRef.of(config) == PrinterRef("printer-3", "Printer 3", None, ("pla",))
    placed = config.model_copy(update={"location": "Room B"})
    assert PrinterRef.of(placed).location == "Room B"


# --- JSON --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "event",
    [
        ev("print_failed", message="Heater extruder not heating", filename="a.gcode"),
        ev("storm_offline", None, location="Room B", count=4, printers=["a", "b"], names=["A"]),
        ev("test", PrinterRef("p", "P", None, ())),
        FleetEvent("printer_offline", datetime(2026, 1, 2, 3, 4, 5, 678, UTC), P3, {"was": "x"}),
    ],
)
def test_an_event_round_trips_through_json(event: FleetEvent) -> None:
    data = event.to_json()
    assert FleetEvent.from_json(data) == event
    assert data["type"] == event.kind
    assert data["severity"] == event.severity


def test_the_json_of_an_event() -> None:
    event = ev("printer_offline", was="printing", filename="tower.gcode")
    assert event.to_json() == {
        "id": event.id,
        "type": "printer_offline",
        "at": "2026-05-01T22:00:00Z",
        "severity": "critical",
        "printer": {
            "id": "printer-3",
            "name": "Printer 3",
            "location": "Room B",
            "tags": ["pla", "big"],
        },
        "data": {"was": "printing", "filename": "tower.gcode"},
    }
    assert len(event.id) == 32
    assert ev().id != ev().id


def test_event_times_are_told_in_utc() -> None:
    madrid = timezone(timedelta(hours=2))
    event = FleetEvent("test", datetime(2026, 5, 2, 0, 0, tzinfo=madrid), None, {})
    assert event.to_json()["at"] == "2026-05-01T22:00:00Z"
    assert FleetEvent.from_json(event.to_json()).at == T0


@pytest.mark.parametrize(
    ("change", "error"),
    [
        ({"type": "printer_exploded"}, ValueError),
        ({"at": "2026-05-01T22:00:00"}, ValueError),
        ({"at": "yesterday"}, ValueError),
    ],
)
def test_json_that_is_not_an_event_is_refused(change: dict[str, Any], error: type) -> None:
    with pytest.raises(error):
        FleetEvent.from_json({**ev().to_json(), **change})


def test_rules_round_trip_through_json() -> None:
    rules = ChannelRules(
        events=frozenset({"print_failed", "storm_offline", "first_layer_done"}),
        printers=("printer-3",),
        locations=("Room B", "Room C"),
        tags=("pla",),
        quiet_hours=QuietHours("22:30", "07:00", allow_critical=False),
        language="es",
        attach_snapshot=False,
        min_role="operator",
    )
    data = rules.to_json()
    assert ChannelRules.from_json(data) == rules
    assert data["events"] == ["print_failed", "first_layer_done", "storm_offline"]
    assert data["quiet_hours"] == {"start": "22:30", "end": "07:00", "allow_critical": False}
    assert ChannelRules.from_json(ChannelRules().to_json()) == ChannelRules()


def test_rules_json_fills_defaults_and_drops_unknown_kinds() -> None:
    assert ChannelRules.from_json({}) == ChannelRules()
    rules = ChannelRules.from_json({"events": ["print_failed", "kind_of_the_future"]})
    assert rules.events == frozenset({"print_failed"})


@pytest.mark.parametrize(
    "data",
    [
        {"events": "print_failed"},
        {"printers": [3]},
        {"language": "fr"},
        {"min_role": "viewer"},
        {"attach_snapshot": "yes"},
        {"quiet_hours": "22:00-07:00"},
        {"quiet_hours": {"start": "22:00"}},
        {"quiet_hours": {"start": "24:00", "end": "07:00"}},
        {"quiet_hours": {"start": "22:00", "end": "7:00"}},
        {"quiet_hours": {"start": "22:00", "end": "07:00", "allow_critical": 1}},
    ],
)
def test_malformed_rules_are_refused(data: dict[str, Any]) -> None:
    with pytest.raises(ValueError):  # noqa: PT011 -- each case has its own message
        ChannelRules.from_json(data)


# --- filters -----------------------------------------------------------------------------


def test_a_channel_gets_the_kinds_it_selected() -> None:
    rules = ChannelRules(events=frozenset({"print_failed"}))
    assert route(rules, ev("print_failed"), NOON) == "deliver"
    assert route(rules, ev("print_completed"), NOON) == "skip"
    assert route(ChannelRules(), ev("first_layer_done"), NOON) == "skip"


@pytest.mark.parametrize(
    ("rules", "deliver"),
    [
        (ChannelRules(printers=("printer-3",)), True),
        (ChannelRules(printers=("printer-4", "printer-5")), False),
        (ChannelRules(locations=("Room B",)), True),
        (ChannelRules(locations=("Room A",)), False),
        (ChannelRules(tags=("petg", "big")), True),
        (ChannelRules(tags=("petg",)), False),
        (ChannelRules(printers=("printer-3",), locations=("Room A",)), False),
    ],
)
def test_a_channel_filters_by_printer_location_and_tag(rules: ChannelRules, deliver: bool) -> None:
    assert route(rules, ev(), NOON) == ("deliver" if deliver else "skip")


def test_a_printer_without_a_location_is_not_in_a_located_channel() -> None:
    nowhere = PrinterRef("p9", "P9", None, ())
    assert route(ChannelRules(locations=("Room B",)), ev(who=nowhere), NOON) == "skip"


def test_fleet_wide_events_are_matched_by_what_they_say_of_themselves() -> None:
    storm = ev("storm_offline", None, location="Room B", count=4, printers=["printer-3", "x"])
    plates = ev("plate_waiting", None, count=2, printers=["printer-8", "printer-9"])
    assert route(ChannelRules(locations=("Room B",)), storm, NOON) == "deliver"
    assert route(ChannelRules(locations=("Room A",)), storm, NOON) == "skip"
    assert route(ChannelRules(locations=("Room A",)), plates, NOON) == "deliver"
    assert route(ChannelRules(printers=("printer-3",)), storm, NOON) == "deliver"
    assert route(ChannelRules(printers=("printer-3",)), plates, NOON) == "skip"
    assert route(ChannelRules(tags=("pla",)), storm, NOON) == "deliver"
    blocked = ev("job_blocked", None, job_id=4, job_name="Brackets", reason="x")
    assert route(ChannelRules(printers=("printer-3",)), blocked, NOON) == "deliver"
    assert route(ChannelRules(events=frozenset({"print_failed"})), storm, NOON) == "skip"


def test_test_events_always_deliver() -> None:
    closed = ChannelRules(
        events=frozenset(),
        printers=("nobody",),
        quiet_hours=QuietHours("00:00", "23:59", allow_critical=False),
    )
    assert route(closed, ev("test", None), NOON) == "deliver"
    assert route(closed, ev("test", P3), time(3, 0)) == "deliver"


# --- quiet hours -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("local", "quiet"),
    [
        (time(21, 59), False),
        (time(22, 0), True),
        (time(23, 59, 59), True),
        (time(0, 0), True),
        (time(3, 30), True),
        (time(6, 59), True),
        (time(7, 0), False),
        (time(12, 0), False),
    ],
)
def test_quiet_hours_wrap_midnight(local: time, quiet: bool) -> None:
    rules = ChannelRules(quiet_hours=QuietHours("22:00", "07:00"))
    assert route(rules, ev("print_completed"), local) == ("quiet_hours" if quiet else "deliver")


@pytest.mark.parametrize(
    ("local", "quiet"),
    [(time(12, 59), False), (time(13, 0), True), (time(13, 59), True), (time(14, 0), False)],
)
def test_quiet_hours_within_a_day(local: time, quiet: bool) -> None:
    assert QuietHours("13:00", "14:00").covers(local) is quiet


def test_equal_start_and_end_are_no_quiet_hours() -> None:
    assert not any(QuietHours("08:00", "08:00").covers(time(h, 0)) for h in range(24))


def test_critical_events_pass_quiet_hours_that_allow_them() -> None:
    night = time(3, 0)
    allowing = ChannelRules(quiet_hours=QuietHours("22:00", "07:00", allow_critical=True))
    strict = ChannelRules(quiet_hours=QuietHours("22:00", "07:00", allow_critical=False))
    offline = ev("printer_offline", was="printing")
    assert route(allowing, offline, night) == "deliver"
    assert route(allowing, ev("plate_waiting"), night) == "quiet_hours"
    assert route(strict, offline, night) == "quiet_hours"


def test_quiet_hours_do_not_change_what_a_channel_skips() -> None:
    rules = ChannelRules(
        events=frozenset({"print_failed"}), quiet_hours=QuietHours("00:00", "23:00")
    )
    assert route(rules, ev("print_completed"), time(3, 0)) == "skip"


def test_quiet_hours_must_be_times_of_day() -> None:
    with pytest.raises(ValueError, match="HH:MM"):
        QuietHours("10pm", "07:00")
