"""Limits that are not known yet, or could not be read, are said so: actions that need them
are refused with a reason, the view shows it, and printers.json's own limits are enough."""

from __future__ import annotations

from dataclasses import replace

import pytest

from kybercore.core.messages import MESSAGES
from kybercore.core.validation import ACTIONS, PrinterFacts, allowed_actions, validate
from kybercore.core.view import LivePrinter, facts, fuse
from kybercore.registry.models import BuildVolume, Capabilities, PrinterConfig

IDLE = PrinterFacts(connection="online", klippy_state="ready", print_state="standby")
NEEDS_LIMITS = {
    "start": {"filename": "cube.gcode"},
    "upload": {"filename": "cube.gcode", "start": True},
    "set_temperature": {"extruder": 200},
    "gcode": {"script": "G1 X10"},
}
CONFIG = PrinterConfig(id="p", name="P", moonraker_url="http://127.0.0.1:7125")
ALL_LIMITS = Capabilities(
    build_volume=BuildVolume(x=220, y=220, z=250),
    nozzle_diameter=0.4,
    max_extruder_temp=280,
    max_bed_temp=110,
)


@pytest.mark.parametrize("limits", ["loading", "unknown"])
@pytest.mark.parametrize("action", ACTIONS)
def test_actions_that_need_limits_are_refused_until_they_are_known(
    limits: str, action: str
) -> None:
    printer = replace(IDLE, limits=limits)
    verdict = validate(action, printer, params=NEEDS_LIMITS.get(action), file_meta={})
    if action in NEEDS_LIMITS:
        assert [(r.code, r.level, r.category) for r in verdict.reasons] == [
            (f"limits_{limits}", "block", "state")
        ]
        # Storing a file needs no limits: the upload button stays (its start is refused).
        assert allowed_actions(printer)[action] == (action == "upload")
    else:  # emergency stop above all: it never waits for anything
        assert f"limits_{limits}" not in [r.code for r in verdict.reasons]
        assert allowed_actions(printer)[action] == allowed_actions(IDLE)[action]


def test_gcode_that_moves_and_heats_nothing_needs_no_limits() -> None:
    printer = replace(IDLE, limits="unknown")
    assert validate("gcode", printer, params={"script": "STATUS\nHELP"}).level == "ok"


def test_another_refusal_comes_first() -> None:
    printer = replace(IDLE, limits="unknown", print_state="printing")
    verdict = validate("start", printer, params={"filename": "a.gcode"}, file_meta={})
    assert [r.code for r in verdict.reasons] == ["print_in_progress"]


@pytest.mark.parametrize("code", ["limits_loading", "limits_unknown"])
def test_the_reasons_say_what_happened_and_what_to_do(code: str) -> None:
    level, category, en, es = MESSAGES[code]
    assert (level, category) == ("block", "state")
    assert "limits" in en
    assert "límites" in es
    assert "printers.json" in en if code == "limits_unknown" else "seconds" in en


def test_the_view_says_whether_the_limits_are_known() -> None:
    online = LivePrinter(connection="online", klippy_state="ready", limits="unknown")
    view = fuse(CONFIG, online)
    assert view["limits"] == "unknown"
    assert not view["actions"]["set_temperature"]
    assert view["actions"]["emergency_stop"]
    online.limits = "known"
    view = fuse(CONFIG, online)
    assert view["limits"] == "known"
    assert view["actions"]["set_temperature"]
    assert LivePrinter().limits == "loading"


def test_limits_from_printers_json_are_enough() -> None:
    configured = CONFIG.model_copy(update={"capabilities": ALL_LIMITS})
    online = LivePrinter(connection="online", klippy_state="ready", limits="unknown")
    assert fuse(configured, online)["limits"] == "known"
    assert facts(configured, online).limits == "known"
    partly = CONFIG.model_copy(update={"capabilities": Capabilities(max_extruder_temp=280)})
    assert facts(partly, online).limits == "unknown"
