"""A notification's observation read back from a fused view (what a front on NATS has) is
that of the live state the view was fused from, and a detector fed either tells the same
events."""

from __future__ import annotations

import dataclasses
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest

from kybercore.core.view import LivePrinter, fuse
from kybercore.notify.detector import Detector, Observation, observe, observe_view
from kybercore.notify.models import FleetEvent, NoiseSettings, PrinterRef
from kybercore.registry.models import PrinterConfig

CONFIG = PrinterConfig(id="p1", name="P1", model="Voron", moonraker_url="http://h:7125")
REF = PrinterRef.of(CONFIG)
T0 = datetime(2026, 5, 1, 22, 0, tzinfo=UTC)
SWITCH = "filament_switch_sensor runout"
MOTION = "filament_motion_sensor encoder"


def status(state: str, **more: Any) -> dict[str, Any]:
    return {
        "webhooks": {"state": "ready"},
        "print_stats": {
            "state": state,
            "filename": "cube.gcode" if state != "standby" else "",
            "message": "",
            "info": {"current_layer": 3 if state in ("printing", "paused") else None},
        },
        **more,
    }


def online(klippy: str = "ready", state: str = "standby", **changes: Any) -> LivePrinter:
    base = LivePrinter(connection="online", klippy_state=klippy, status=status(state))
    return dataclasses.replace(base, **changes)


def with_stats(live: LivePrinter, **stats: Any) -> LivePrinter:
    merged = {**live.status, "print_stats": {**live.status["print_stats"], **stats}}
    return dataclasses.replace(live, status=merged)


def sensor(name: str, detected: bool, enabled: bool = True) -> dict[str, Any]:
    return {name: {"filament_detected": detected, "enabled": enabled}}


PRINTING = online(state="printing")
CASES: dict[str, LivePrinter] = {
    "ready idle": online(),
    "printing": PRINTING,
    "paused": online(state="paused"),
    "complete": online(state="complete"),
    "cancelled": online(state="cancelled"),
    "failed": with_stats(online(state="error"), message="Move out of range: 300.000"),
    "shut down mid-print": online("shutdown", "printing", klippy_message="MCU 'mcu' shutdown"),
    "klippy error": online("error", "standby", klippy_message="Unable to open config"),
    "startup": online("startup", "printing"),
    "offline": LivePrinter(connection="offline", connection_error="refused"),
    "connecting": LivePrinter(),
    "auth failed": LivePrinter(connection="auth_failed"),
    "no layers reported": with_stats(PRINTING, info={}),
    "a layer that is no number": with_stats(PRINTING, info={"current_layer": "7"}),
    "a boolean layer": with_stats(PRINTING, info={"current_layer": True}),
    "no print_stats": online(status={"webhooks": {"state": "ready"}}),
    "runout (switch)": online(
        state="paused", status={**status("paused"), **sensor(SWITCH, detected=False)}
    ),
    "runout (motion)": online(
        state="paused", status={**status("paused"), **sensor(MOTION, detected=False)}
    ),
    "filament present": online(status={**status("printing"), **sensor(SWITCH, detected=True)}),
    "a disabled sensor": online(
        status={**status("paused"), **sensor(SWITCH, detected=False, enabled=False)}
    ),
}


@pytest.mark.parametrize("live", CASES.values(), ids=CASES.keys())
def test_the_observation_of_the_view_is_that_of_the_live_state(live: LivePrinter) -> None:
    from_live = observe(live)
    from_view = observe_view(fuse(CONFIG, live))
    if live.klippy_state == "ready":
        assert from_view == from_live
    else:
        # fuse() blanks the job's state while Klippy is not ready; nothing else differs.
        assert from_view == dataclasses.replace(from_live, print_state=None)


def test_the_display_message_stands_in_for_an_empty_print_message() -> None:
    shown = online(state="printing", status={**status("printing"),
                                             "display_status": {"message": "Layer 3"}})  # fmt: skip
    assert observe(shown).print_message == ""
    assert observe_view(fuse(CONFIG, shown)).print_message == "Layer 3"
    failed = with_stats(shown, state="error", message="Heater extruder not heating")
    assert observe_view(fuse(CONFIG, failed)).print_message == "Heater extruder not heating"


def test_the_view_says_whether_the_filament_ran_out() -> None:
    assert fuse(CONFIG, CASES["runout (switch)"])["runout"] is True
    assert fuse(CONFIG, CASES["a disabled sensor"])["runout"] is False
    assert fuse(CONFIG, online())["runout"] is False


def feed(observations: list[Observation]) -> list[tuple[str, datetime, dict[str, Any]]]:
    """The events a fresh detector tells, without their (random) ids."""
    detector = Detector(NoiseSettings())
    events: list[FleetEvent] = []
    for second, observation in enumerate(observations):
        at = T0 + timedelta(seconds=second)
        events += detector.observe(REF, observation, float(second), at)
    return [(event.kind, event.at, event.params) for event in events]


STORIES: dict[str, list[LivePrinter]] = {
    "a print from start to end": [
        online(), PRINTING, with_stats(PRINTING, info={"current_layer": 1}),
        with_stats(PRINTING, info={"current_layer": 2}), online(state="complete"),
    ],
    "a runout pause, then a failure": [
        PRINTING, CASES["runout (switch)"], CASES["failed"],
    ],
    "Klippy shut down mid-print, then back": [
        PRINTING, CASES["shut down mid-print"], online("startup", "printing"), online(),
    ],
    "lost while printing, back finished": [
        PRINTING, CASES["offline"], online("disconnected", "complete"), online(state="complete"),
    ],
    "a restart finding a print": [
        LivePrinter(), online("disconnected", "printing"), PRINTING, online(state="complete"),
    ],
    "cancelled": [PRINTING, online(state="paused"), online(state="cancelled")],
}  # fmt: skip


@pytest.mark.parametrize("story", STORIES.values(), ids=STORIES.keys())
def test_a_detector_tells_the_same_events_from_the_views(story: list[LivePrinter]) -> None:
    from_live = feed([observe(live) for live in story])
    assert from_live  # every story is news
    assert feed([observe_view(fuse(CONFIG, live)) for live in story]) == from_live
