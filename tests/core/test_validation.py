"""Every validation rule, on both sides: what passes and what is warned or blocked.

The last part parses the sample G-code files in tests/samples/gcode with Moonraker's own
metadata parser and validates them against a small fleet, so the metadata the rules read is
known to be what a real Moonraker reports.
"""

from __future__ import annotations

import json
import shutil
import string
import subprocess
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from kybercore.core.messages import MESSAGES, Reason
from kybercore.core.validation import (
    ACTIONS,
    MAX_SCRIPT_BYTES,
    PrinterFacts,
    Verdict,
    allowed_actions,
    filament_types,
    validate,
)
from kybercore.sim.runtime import MOONRAKER

SAMPLES = Path(__file__).parents[1] / "samples" / "gcode"

IDLE = PrinterFacts(
    connection="online",
    klippy_state="ready",
    print_state="standby",
    model="Prusa MK4",
    build_volume=(250.0, 210.0, 220.0),
    nozzle_diameter=0.4,
    material="PLA",
    max_extruder_temp=290.0,
    max_bed_temp=120.0,
)
PRINTING = replace(IDLE, print_state="printing")
PAUSED = replace(IDLE, print_state="paused")


def meta(**overrides: Any) -> dict[str, Any]:
    """A `/server/files/metadata` result as Moonraker 0.11 returns it for a PrusaSlicer file."""
    base: dict[str, Any] = {
        "size": 1_234_567,
        "modified": 1_710_236_487.5,
        "uuid": "0f6b1ac8-5d0e-4b1b-9a6e-3f1b2c4d5e6f",
        "file_processors": [],
        "slicer": "PrusaSlicer",
        "slicer_version": "2.7.1+linux-x64-GTK3",
        "gcode_start_byte": 532,
        "gcode_end_byte": 1_230_519,
        "object_height": 20.0,
        "estimated_time": 2592,
        "nozzle_diameter": 0.4,
        "layer_height": 0.2,
        "first_layer_height": 0.2,
        "first_layer_extr_temp": 215.0,
        "first_layer_bed_temp": 60.0,
        "filament_name": "Prusament PLA",
        "filament_type": "PLA",
        "filament_colors": ["#FF8000"],
        "filament_temps": [215],
        "filament_total": 412.37,
        "filament_weight_total": 1.23,
        "mmu_print": 0,
        "printer_model": "MK4",
        "printer_variant": "0.4",
        "thumbnails": [
            {
                "width": 32,
                "height": 32,
                "size": 118,
                "relative_path": ".thumbs/cube-32x32.png",
            }
        ],
        "filename": "cube.gcode",
    }
    base.update(overrides)
    return base


def codes(verdict: Verdict) -> list[str]:
    return [r.code for r in verdict.reasons]


def start(printer: PrinterFacts = IDLE, **overrides: Any) -> Verdict:
    return validate(
        "start", printer, params={"filename": "cube.gcode"}, file_meta=meta(**overrides)
    )


def gcode(script: str, printer: PrinterFacts = IDLE, *, force: bool = False) -> Verdict:
    return validate("gcode", printer, params={"script": script}, force=force)


def only(verdict: Verdict) -> Reason:
    assert len(verdict.reasons) == 1, verdict
    return verdict.reasons[0]


# --- verdict and message basics ------------------------------------------------------------


def test_verdict_level_is_the_worst_reason() -> None:
    warn = Reason("w", "warn", "compatibility", "w", "w")
    block = Reason("b", "block", "state", "b", "b")
    assert Verdict.of([]).level == "ok"
    assert Verdict.of([warn]).level == "warn"
    verdict = Verdict.of([warn, block])
    assert verdict.level == "block"
    assert verdict.blocked
    assert verdict.warnings == (warn,)
    assert not Verdict.of([warn]).blocked


def test_blocking_category_prefers_connection_then_state() -> None:
    limit = Reason("l", "block", "limit", "l", "l")
    state = Reason("s", "block", "state", "s", "s")
    warn_conn = Reason("c", "warn", "connection", "c", "c")
    assert Verdict.of([limit, state, warn_conn]).blocking_category == "state"
    assert Verdict.of([limit]).blocking_category == "limit"
    assert Verdict.of([warn_conn]).blocking_category is None


@pytest.mark.parametrize("code", sorted(MESSAGES))
def test_every_message_has_both_languages_with_the_same_placeholders(code: str) -> None:
    level, category, en, es = MESSAGES[code]
    assert level in ("warn", "block")
    assert category in ("state", "limit", "compatibility", "connection")
    assert en
    assert es
    assert en != es
    # A placeholder ending in _en or _es is the same value in that language.
    fields = [
        {f.removesuffix(suffix) for _, f, _, _ in string.Formatter().parse(text) if f}
        for text, suffix in ((en, "_en"), (es, "_es"))
    ]
    assert fields[0] == fields[1]
    assert code == code.lower()
    assert " " not in code


# --- connection -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("connection", "code"),
    [
        ("offline", "printer_offline"),
        ("connecting", "printer_connecting"),
        ("auth_failed", "printer_auth_failed"),
        ("something-new", "printer_offline"),
    ],
)
@pytest.mark.parametrize("action", ACTIONS)
def test_no_connection_blocks_every_action(connection: str, code: str, action: str) -> None:
    printer = replace(IDLE, connection=connection)
    reason = only(validate(action, printer, params={"script": "G28", "filename": "a.gcode"}))
    assert (reason.code, reason.level, reason.category) == (code, "block", "connection")
    assert allowed_actions(printer) == dict.fromkeys(ACTIONS, False)


def test_unknown_action_is_blocked_and_lists_the_valid_ones() -> None:
    reason = only(validate("explode", IDLE))
    assert (reason.code, reason.level, reason.category) == ("unknown_action", "block", "limit")
    assert "emergency_stop" in reason.en
    assert "emergency_stop" in reason.es
    assert "explode" in reason.en


# --- Klippy state ---------------------------------------------------------------------------


@pytest.mark.parametrize("klippy", ["shutdown", "error"])
@pytest.mark.parametrize("action", ACTIONS)
def test_klippy_down_allows_only_restarts_and_emergency_stop(klippy: str, action: str) -> None:
    printer = replace(IDLE, klippy_state=klippy, print_state="error")
    params = {"filename": "cube.gcode", "script": "G28", "extruder": 200, "start": True}
    verdict = validate(action, printer, params=params, file_meta=meta())
    if action == "restart" and klippy == "shutdown":
        assert codes(verdict) == ["restart_after_shutdown"]
    elif action in ("firmware_restart", "restart", "emergency_stop"):
        assert verdict.level == "ok"
    elif action == "upload":  # with start=True it needs Klippy like start does
        assert codes(verdict) == [f"klippy_{klippy}"]
    else:
        assert f"klippy_{klippy}" in codes(verdict)
        assert verdict.blocking_category == "state"


@pytest.mark.parametrize("script", ["FIRMWARE_RESTART", "firmware_restart ; again", "STATUS\nHELP"])
def test_klippy_shutdown_still_accepts_the_gcode_klippy_runs_when_down(script: str) -> None:
    printer = replace(IDLE, klippy_state="shutdown")
    assert gcode(script, printer).level == "ok"


def test_after_a_shutdown_only_a_firmware_restart_brings_klippy_back() -> None:
    # A shutdown stops the MCU too; a host restart then fails with "Can not update MCU
    # config as it is shutdown" and leaves Klippy in error.
    down = replace(IDLE, klippy_state="shutdown")
    for verdict in (
        validate("restart", down),
        gcode("RESTART", down),
        gcode("STATUS\nRESTART", down),
    ):
        reason = only(verdict)
        assert (reason.code, reason.level, reason.category) == (
            "restart_after_shutdown",
            "block",
            "state",
        )
        assert "firmware restart" in reason.en
        assert "reinicio del firmware" in reason.es
    assert validate("firmware_restart", down).level == "ok"
    assert not allowed_actions(down)["restart"]
    # A Klippy in error (a configuration mistake) is what a host restart is for.
    broken = replace(IDLE, klippy_state="error")
    assert validate("restart", broken).level == "ok"
    assert gcode("RESTART", broken).level == "ok"


def test_klippy_shutdown_blocks_other_gcode() -> None:
    printer = replace(IDLE, klippy_state="shutdown")
    assert codes(gcode("FIRMWARE_RESTART\nG28", printer)) == ["klippy_shutdown"]


@pytest.mark.parametrize(
    ("klippy", "code"), [("startup", "klippy_startup"), ("disconnected", "klippy_disconnected")]
)
def test_klippy_not_ready_says_wait(klippy: str, code: str) -> None:
    printer = replace(IDLE, klippy_state=klippy)
    for action in ("start", "home", "restart", "firmware_restart", "gcode"):
        reason = validate(action, printer, params={"script": "G28"}).reasons[0]
        assert (reason.code, reason.level, reason.category) == (code, "block", "state")
        assert "Wait" in reason.en
        assert "Espere" in reason.es
    assert validate("emergency_stop", printer).level == "ok"


# --- print state -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("action", "ok_states", "code"),
    [
        ("pause", {"printing"}, "pause_not_printing"),
        ("resume", {"paused"}, "resume_not_paused"),
        ("cancel", {"printing", "paused"}, "cancel_no_print"),
        ("home", {"standby", "complete", "cancelled", "error", ""}, "home_while_printing"),
    ],
)
@pytest.mark.parametrize("state", ["standby", "printing", "paused", "complete", "cancelled", ""])
def test_print_state_rules(action: str, ok_states: set[str], code: str, state: str) -> None:
    verdict = validate(action, replace(IDLE, print_state=state))
    if state in ok_states:
        assert verdict.level == "ok"
    else:
        reason = only(verdict)
        assert (reason.code, reason.level, reason.category) == (code, "block", "state")


@pytest.mark.parametrize("state", ["standby", "complete", "cancelled", "error"])
def test_start_is_ok_when_no_print_is_running(state: str) -> None:
    assert start(replace(IDLE, print_state=state)).level == "ok"


@pytest.mark.parametrize("printer", [PRINTING, PAUSED])
def test_start_is_blocked_while_a_print_runs_or_is_paused(printer: PrinterFacts) -> None:
    verdict = start(printer)
    assert codes(verdict) == ["print_in_progress"]
    assert verdict.blocking_category == "state"


def test_start_reports_every_problem_at_once_for_the_dry_run() -> None:
    verdict = start(PRINTING, object_height=300.0)
    assert codes(verdict) == ["print_in_progress", "file_too_tall"]


@pytest.mark.parametrize("action", ["restart", "firmware_restart"])
@pytest.mark.parametrize("printer", [PRINTING, PAUSED])
def test_restarts_during_a_print_need_force(action: str, printer: PrinterFacts) -> None:
    blocked = only(validate(action, printer))
    assert (blocked.code, blocked.level, blocked.category) == (
        "restart_while_printing",
        "block",
        "state",
    )
    assert "force" in blocked.en
    assert "force" in blocked.es
    forced = validate(action, printer, force=True)
    assert forced.level == "warn"
    assert codes(forced) == ["forced_during_print"]
    assert validate(action, IDLE).level == "ok"


def test_set_temperature_is_allowed_during_a_print() -> None:
    assert validate("set_temperature", PRINTING, params={"extruder": 220}).level == "ok"


@pytest.mark.parametrize("printer", [IDLE, PRINTING, replace(IDLE, klippy_state="shutdown")])
def test_emergency_stop_is_always_allowed_when_connected(printer: PrinterFacts) -> None:
    assert validate("emergency_stop", printer).level == "ok"


def test_allowed_actions_follow_state() -> None:
    idle = allowed_actions(IDLE)
    assert idle["start"]
    assert idle["home"]
    assert idle["gcode"]
    assert not idle["pause"]
    printing = allowed_actions(PRINTING)
    assert printing["pause"]
    assert printing["cancel"]
    assert printing["set_temperature"]
    assert not printing["start"]
    assert not printing["home"]
    assert not printing["restart"]
    assert printing["emergency_stop"]
    assert printing["upload"]
    paused = allowed_actions(PAUSED)
    assert paused["resume"]
    assert paused["cancel"]
    assert not paused["pause"]
    down = allowed_actions(replace(IDLE, klippy_state="shutdown"))
    assert {a for a, ok in down.items() if ok} == {
        "firmware_restart",
        "emergency_stop",
        "upload",
    }


# --- starting and uploading a file ----------------------------------------------------------


def test_matching_file_is_ok() -> None:
    assert start().reasons == ()


def test_missing_filename_is_blocked() -> None:
    for params in ({}, {"filename": "  "}, {"filename": 3}):
        verdict = validate("start", IDLE, params=params, file_meta=meta())
        assert codes(verdict) == ["filename_missing"]
        assert verdict.blocking_category == "limit"


def test_unknown_metadata_warns_on_start_but_not_on_a_plain_upload() -> None:
    verdict = validate("start", IDLE, params={"filename": "a.gcode"})
    reason = only(verdict)
    assert (reason.code, reason.level, reason.category) == (
        "file_metadata_missing",
        "warn",
        "compatibility",
    )
    upload = validate("upload", IDLE, params={"filename": "a.gcode"})
    assert upload.level == "ok"
    upload_start = validate("upload", IDLE, params={"filename": "a.gcode", "start": True})
    assert codes(upload_start) == ["file_metadata_missing"]


def test_too_tall_is_blocked() -> None:
    reason = only(start(object_height=220.5))
    assert (reason.code, reason.level, reason.category) == (
        "file_too_tall",
        "block",
        "compatibility",
    )
    assert "220.5" in reason.en
    assert "220,5" in reason.es
    assert start(object_height=220.0).level == "ok"
    assert start(replace(IDLE, build_volume=None), object_height=999).level == "ok"


def test_nozzle_mismatch_is_blocked_beyond_the_tolerance() -> None:
    reason = only(start(nozzle_diameter=0.6))
    assert (reason.code, reason.level) == ("nozzle_mismatch", "block")
    assert "0.6" in reason.en
    assert "0,4" in reason.es
    assert start(nozzle_diameter=0.409).level == "ok"
    assert start(nozzle_diameter=None).level == "ok"
    assert start(replace(IDLE, nozzle_diameter=None), nozzle_diameter=0.6).level == "ok"


def test_filament_mismatch_warns() -> None:
    reason = only(start(filament_type="PETG"))
    assert (reason.code, reason.level, reason.category) == (
        "filament_mismatch",
        "warn",
        "compatibility",
    )
    assert "PETG" in reason.en
    assert "PLA" in reason.es
    assert start(filament_type="pla").level == "ok"
    assert start(replace(IDLE, material=" pla ")).level == "ok"


def test_filament_check_needs_both_sides() -> None:
    assert start(replace(IDLE, material=None), filament_type="PETG").level == "ok"
    assert start(replace(IDLE, material=""), filament_type="PETG").level == "ok"
    assert start(filament_type=None).level == "ok"


def test_multi_material_files_match_when_the_loaded_filament_is_among_them() -> None:
    assert start(filament_type='["PLA", "PETG"]').level == "ok"
    assert codes(start(filament_type='["ASA", "PETG"]')) == ["filament_mismatch"]


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        ("PLA", ("PLA",)),
        (" petg ", ("PETG",)),
        ('["PLA", "PLA"]', ("PLA",)),
        ('["PLA", "PETG"]', ("PLA", "PETG")),
        ("PLA;PETG", ("PLA", "PETG")),
        ("[not json", ("[NOT JSON",)),
        ("", ()),
        (None, ()),
        (3, ()),
    ],
)
def test_filament_types(value: Any, expected: tuple[str, ...]) -> None:
    assert filament_types(value) == expected


def test_first_layer_temperatures_over_max_are_blocked() -> None:
    reason = only(start(first_layer_extr_temp=300.0))
    assert (reason.code, reason.level, reason.category) == (
        "file_extruder_temp_over_max",
        "block",
        "limit",
    )
    assert "300" in reason.en
    assert "290" in reason.es
    assert codes(start(first_layer_bed_temp=125.0)) == ["file_bed_temp_over_max"]
    assert start(first_layer_extr_temp=290.0, first_layer_bed_temp=120.0).level == "ok"
    unknown_max = replace(IDLE, max_extruder_temp=None, max_bed_temp=None)
    assert start(unknown_max, first_layer_extr_temp=400, first_layer_bed_temp=200).level == "ok"


def test_file_sliced_for_another_printer_model_warns() -> None:
    reason = only(start(printer_model="Voron 2.4 300"))
    assert (reason.code, reason.level, reason.category) == (
        "printer_model_mismatch",
        "warn",
        "compatibility",
    )
    assert "Voron 2.4 300" in reason.es
    assert "Prusa MK4" in reason.en


@pytest.mark.parametrize(
    ("ours", "sliced_for"),
    [("Prusa MK4", "MK4"), ("Voron 2.4", "voron2.4"), ("", "MK4"), ("Prusa MK4", ""), ("X", "-")],
)
def test_printer_model_that_matches_or_is_unknown_does_not_warn(ours: str, sliced_for: str) -> None:
    assert start(replace(IDLE, model=ours), printer_model=sliced_for).level == "ok"
    assert start(replace(IDLE, model=ours), printer_model=None).level == "ok"


def test_junk_metadata_values_are_ignored_and_numeric_strings_read() -> None:
    assert (
        start(object_height="tall", nozzle_diameter=True, first_layer_extr_temp=[1]).level == "ok"
    )
    assert codes(start(object_height="300")) == ["file_too_tall"]
    assert start(object_height=float("nan")).level == "ok"


def test_upload_without_start_only_warns_about_the_file() -> None:
    params = {"filename": "tall.gcode"}
    stored = validate("upload", PRINTING, params=params, file_meta=meta(object_height=300))
    assert stored.level == "warn"
    assert codes(stored) == ["file_too_tall"]
    started = validate(
        "upload", IDLE, params={**params, "start": True}, file_meta=meta(object_height=300)
    )
    assert started.level == "block"
    assert codes(started) == ["file_too_tall"]


# --- set_temperature and home parameters -----------------------------------------------------


def test_temperatures_within_limits_are_ok() -> None:
    params = {"extruder": 290, "bed": 120.0}
    assert validate("set_temperature", IDLE, params=params).level == "ok"
    assert validate("set_temperature", IDLE, params={"extruder": 0, "bed": None}).level == "ok"


def test_temperatures_over_max_are_blocked() -> None:
    verdict = validate("set_temperature", IDLE, params={"extruder": 291, "bed": 121})
    assert codes(verdict) == ["extruder_temp_over_max", "bed_temp_over_max"]
    assert verdict.blocking_category == "limit"
    assert "291" in verdict.reasons[0].en
    assert "290" in verdict.reasons[0].es


def test_temperature_without_known_max_is_not_limited() -> None:
    printer = replace(IDLE, max_extruder_temp=None)
    assert validate("set_temperature", printer, params={"extruder": 500}).level == "ok"


def test_temperature_must_be_given() -> None:
    for params in ({}, {"extruder": None, "bed": None}):
        assert codes(validate("set_temperature", IDLE, params=params)) == ["temperature_missing"]


@pytest.mark.parametrize("value", [-1, "200", True, float("nan"), float("inf"), [200]])
def test_temperature_must_be_a_non_negative_number(value: Any) -> None:
    verdict = validate("set_temperature", IDLE, params={"bed": value})
    assert codes(verdict) == ["temperature_invalid"]
    assert "la cama" in verdict.reasons[0].es


@pytest.mark.parametrize("axes", [None, "", "xyz", "XY", "z"])
def test_home_axes_ok(axes: str | None) -> None:
    assert validate("home", IDLE, params={"axes": axes}).level == "ok"


@pytest.mark.parametrize("axes", ["xe", "abc", 3])
def test_home_axes_invalid(axes: Any) -> None:
    assert codes(validate("home", IDLE, params={"axes": axes})) == ["home_axes_invalid"]


# --- G-code scripts -----------------------------------------------------------------------------


def test_ordinary_script_is_ok() -> None:
    assert gcode("G28\nG90\nG1 X100 Y100 Z10 F3000\nM104 S200 ; preheat").reasons == ()


@pytest.mark.parametrize("script", ["", "   \n", "; only a comment\n;M112", None, 42])
def test_empty_script_is_blocked(script: Any) -> None:
    verdict = validate("gcode", IDLE, params={"script": script})
    assert codes(verdict) == ["gcode_empty"]
    assert verdict.blocking_category == "limit"


def test_script_over_64_kib_is_blocked() -> None:
    line = "G4 P0\n"
    at_limit = line * (MAX_SCRIPT_BYTES // len(line))
    assert gcode(at_limit).level == "ok"
    over = at_limit + line
    assert codes(gcode(over)) == ["gcode_too_long"]
    assert gcode("ñ" * (MAX_SCRIPT_BYTES // 2 + 1)).reasons[0].code == "gcode_too_long"


@pytest.mark.parametrize("script", ["M112", "m112", "G28\nM112 ; stop!", "N5 M112*12"])
def test_m112_is_blocked_with_use_emergency_stop(script: str) -> None:
    reason = gcode(script).reasons[0]
    assert (reason.code, reason.level) == ("gcode_m112", "block")
    assert "emergency stop" in reason.en
    assert "parada de emergencia" in reason.es


@pytest.mark.parametrize("command", ["SAVE_CONFIG", "FIRMWARE_RESTART", "restart"])
def test_restart_commands_while_printing_need_force(command: str) -> None:
    for printer in (PRINTING, PAUSED):
        reason = only(gcode(command, printer))
        assert (reason.code, reason.level, reason.category) == (
            "gcode_restart_while_printing",
            "block",
            "state",
        )
        assert command.upper() in reason.en
        assert "force" in reason.es
        assert codes(gcode(command, printer, force=True)) == ["forced_during_print"]
    assert gcode(command, IDLE).level == "ok"


def test_g28_in_a_script_while_printing_needs_force() -> None:
    assert codes(gcode("G28 Z", PRINTING)) == ["gcode_home_while_printing"]
    assert gcode("G28 Z", PRINTING, force=True).level == "warn"
    assert gcode("M117 homing later; G28", PRINTING).level == "ok"


@pytest.mark.parametrize(
    ("script", "code"),
    [
        ("M104 S291", "gcode_extruder_temp_over_max"),
        ("M109 S300", "gcode_extruder_temp_over_max"),
        ("SET_HEATER_TEMPERATURE HEATER=extruder TARGET=295", "gcode_extruder_temp_over_max"),
        ("M140 S121", "gcode_bed_temp_over_max"),
        ("m190 s130", "gcode_bed_temp_over_max"),
        ("SET_HEATER_TEMPERATURE HEATER=heater_bed TARGET=150", "gcode_bed_temp_over_max"),
    ],
)
def test_script_temperatures_over_max_are_blocked(script: str, code: str) -> None:
    reason = only(gcode(script))
    assert (reason.code, reason.level, reason.category) == (code, "block", "limit")
    assert script in reason.en
    assert "línea 1" in reason.es


def test_script_temperatures_within_limits_or_unknown_max_are_ok() -> None:
    assert gcode("M104 S290\nM140 S120\nM109 S0").level == "ok"
    unknown = replace(IDLE, max_extruder_temp=None, max_bed_temp=None)
    assert gcode("M104 S900\nM140 S900", unknown).level == "ok"


def test_move_outside_the_volume_warns() -> None:
    reason = only(gcode("G28\nG90\nG1 X100\nG1 Y230 F6000"))
    assert (reason.code, reason.level, reason.category) == (
        "gcode_move_outside_volume",
        "warn",
        "limit",
    )
    assert "4" in reason.en
    assert "G1 Y230 F6000" in reason.es
    assert "0–210 mm" in reason.en


def test_moves_inside_or_uncertain_do_not_warn() -> None:
    assert gcode("G90\nG1 X250 Y210 Z220").level == "ok"
    assert gcode("G91\nG1 X200").level == "ok"
    assert gcode("G90\nG1 X900", replace(IDLE, build_volume=None)).level == "ok"


def test_axis_minimum_widens_the_range_and_never_narrows_it() -> None:
    printer = replace(IDLE, axis_minimum=(-5.0, -5.0, -2.0))
    assert gcode("G90\nG1 X-4 Y250", printer).level == "warn"  # Y: -5..210
    assert gcode("G90\nG1 X-4 Y209 Z219", printer).level == "ok"
    assert codes(gcode("G90\nG1 Z-3", printer)) == ["gcode_move_outside_volume"]
    shifted = replace(IDLE, axis_minimum=(10.0, 0.0, 0.0))
    assert gcode("G90\nG1 X255", shifted).level == "ok"  # 10 + 250
    assert gcode("G90\nG1 X5", shifted).level == "warn"


# --- the sample files through Moonraker's own metadata parser ----------------------------------

SAMPLE_NAMES = sorted(p.name for p in SAMPLES.glob("*.gcode"))


@pytest.fixture(scope="module")
def moonraker_metadata(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Each sample's metadata as Moonraker 0.11's metadata.py reports it."""
    if not MOONRAKER.installed():
        pytest.skip(
            f"Moonraker's environment is not installed at {MOONRAKER.root}; the integration "
            "tests install it (kybercore.sim.runtime.ensure_runtimes)"
        )
    # A folder per file: the parser writes .thumbs/ next to the file, and two parsers
    # creating the same .thumbs/ at once made one give up on its thumbnails.
    folders = {name: tmp_path_factory.mktemp("gcodes") for name in SAMPLE_NAMES}
    for name, folder in folders.items():
        shutil.copy(SAMPLES / name, folder / name)
    procs = {
        name: subprocess.Popen(
            [
                str(MOONRAKER.python),
                "-m",
                "moonraker.components.file_manager.metadata",
                "-f",
                name,
                "-p",
                str(folders[name]),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        for name in SAMPLE_NAMES
    }
    parsed: dict[str, Any] = {}
    for name, proc in procs.items():
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err.decode()
        result = json.loads(out)
        assert result["file"] == name
        parsed[name] = result["metadata"]
    return parsed


EXPECTED_METADATA = {
    "prusaslicer_cube_20mm_pla.gcode": {
        "slicer": "PrusaSlicer", "object_height": 20.0, "nozzle_diameter": 0.4,
        "filament_type": "PLA", "first_layer_extr_temp": 215.0, "first_layer_bed_temp": 60.0,
        "estimated_time": 2592, "printer_model": "MK4",
    },
    "prusaslicer_cube_15mm_petg_06nozzle.gcode": {
        "slicer": "PrusaSlicer", "object_height": 15.05, "nozzle_diameter": 0.6,
        "filament_type": "PETG", "first_layer_extr_temp": 240.0, "first_layer_bed_temp": 80.0,
        "estimated_time": 1660, "printer_model": "MK4",
    },
    "orcaslicer_cube_20mm_pla.gcode": {
        "slicer": "OrcaSlicer", "object_height": 20.0, "nozzle_diameter": 0.4,
        "filament_type": "PLA", "first_layer_extr_temp": 220.0, "first_layer_bed_temp": 60.0,
        "estimated_time": 2482, "printer_model": "Voron 2.4 300",
    },
    "orcaslicer_pc_first_layer_300c.gcode": {
        "slicer": "OrcaSlicer", "object_height": 10.0, "nozzle_diameter": 0.4,
        "filament_type": "PC", "first_layer_extr_temp": 300.0, "first_layer_bed_temp": 100.0,
        "estimated_time": 1446, "printer_model": "Voron 2.4 300",
    },
    "cura_cube_20mm_pla.gcode": {
        "slicer": "Cura", "object_height": 20.0, "nozzle_diameter": 0.4,
        "filament_type": "PLA", "first_layer_extr_temp": 200.0, "first_layer_bed_temp": 60.0,
        "estimated_time": 2489.0,
    },
    "cura_tall_300mm_pla.gcode": {
        "slicer": "Cura", "object_height": 300.0, "nozzle_diameter": 0.4,
        "filament_type": "PLA", "first_layer_extr_temp": 200.0, "first_layer_bed_temp": 60.0,
        "estimated_time": 61234.0,
    },
}  # fmt: skip


def test_every_sample_file_has_expectations() -> None:
    assert sorted(EXPECTED_METADATA) == SAMPLE_NAMES


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_moonraker_reads_what_the_rules_need(moonraker_metadata: dict[str, Any], name: str) -> None:
    found = moonraker_metadata[name]
    expected = EXPECTED_METADATA[name]
    assert {key: found.get(key) for key in expected} == expected
    assert found["size"] == (SAMPLES / name).stat().st_size
    if found["slicer"] != "Cura":  # PrusaSlicer and Orca embed a thumbnail
        assert found["thumbnails"][0]["width"] == 32


def fleet_printer(model: str, z: float, *, nozzle: float = 0.4, material: str = "PLA",
                  max_extruder: float = 280.0) -> PrinterFacts:  # fmt: skip
    return PrinterFacts(
        connection="online",
        klippy_state="ready",
        print_state="standby",
        model=model,
        build_volume=(220.0, 220.0, z),
        nozzle_diameter=nozzle,
        material=material,
        max_extruder_temp=max_extruder,
        max_bed_temp=110.0,
    )


# A small fleet: the integration tests' virtual printer (220x220x250, 0.4 mm, max 280/110 °C)
# and printers that differ from it in one or two ways each.
FLEET = {
    "sim-250": fleet_printer("KyberCore virtual printer", 250.0),
    "tall-350": fleet_printer("KyberCore virtual printer", 350.0),
    "mk4-06-petg": fleet_printer("Prusa MK4", 220.0, nozzle=0.6, material="PETG"),
    "voron-hot": fleet_printer("Voron 2.4 300", 280.0, material="PC", max_extruder=350.0),
}

# (file, printer): the reason codes validate() gives for starting that file there.
FLEET_EXPECTED = {
    ("cura_tall_300mm_pla.gcode", "sim-250"): ["file_too_tall"],
    ("cura_tall_300mm_pla.gcode", "tall-350"): [],
    ("cura_tall_300mm_pla.gcode", "voron-hot"): ["file_too_tall", "filament_mismatch"],
    ("cura_cube_20mm_pla.gcode", "sim-250"): [],
    ("prusaslicer_cube_20mm_pla.gcode", "sim-250"): ["printer_model_mismatch"],
    ("prusaslicer_cube_20mm_pla.gcode", "mk4-06-petg"): ["nozzle_mismatch", "filament_mismatch"],
    ("prusaslicer_cube_15mm_petg_06nozzle.gcode", "sim-250"): [
        "nozzle_mismatch", "filament_mismatch", "printer_model_mismatch",
    ],
    ("prusaslicer_cube_15mm_petg_06nozzle.gcode", "mk4-06-petg"): [],
    ("orcaslicer_cube_20mm_pla.gcode", "voron-hot"): ["filament_mismatch"],
    ("orcaslicer_cube_20mm_pla.gcode", "tall-350"): ["printer_model_mismatch"],
    ("orcaslicer_pc_first_layer_300c.gcode", "sim-250"): [
        "filament_mismatch", "file_extruder_temp_over_max", "printer_model_mismatch",
    ],
    ("orcaslicer_pc_first_layer_300c.gcode", "voron-hot"): [],
}  # fmt: skip


@pytest.mark.parametrize(("name", "printer"), sorted(FLEET_EXPECTED))
def test_fleet_verdicts_from_real_moonraker_metadata(
    moonraker_metadata: dict[str, Any], name: str, printer: str
) -> None:
    verdict = validate(
        "start",
        FLEET[printer],
        params={"filename": name},
        file_meta=moonraker_metadata[name],
    )
    assert codes(verdict) == FLEET_EXPECTED[(name, printer)]


def test_tall_file_is_blocked_on_the_short_printer_and_accepted_on_the_tall_one(
    moonraker_metadata: dict[str, Any],
) -> None:
    name = "cura_tall_300mm_pla.gcode"
    verdicts = {
        printer: validate("start", FLEET[printer], params={"filename": name},
                          file_meta=moonraker_metadata[name])
        for printer in ("sim-250", "tall-350")
    }  # fmt: skip
    assert verdicts["sim-250"].blocked
    assert verdicts["sim-250"].blocking_category == "compatibility"
    assert "300 mm" in verdicts["sim-250"].reasons[0].en
    assert verdicts["tall-350"].level == "ok"
