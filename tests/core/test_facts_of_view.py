"""Validation's facts read back from a fused view (what a front on NATS has) are those of
the live state the view was fused from."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest
from pydantic import SecretStr

from kybercore.core.spools import Spool
from kybercore.core.validation import ACTIONS, PrinterFacts, allowed_actions, validate
from kybercore.core.view import LivePrinter, facts, facts_of_view, fuse
from kybercore.registry.models import BuildVolume, Capabilities, PrinterConfig

PLAIN = PrinterConfig(id="plain", name="Plain", model="Voron", moonraker_url="http://h:7125")
CONFIGURED = PrinterConfig(
    id="configured",
    name="Configured",
    model="Prusa MK4",
    moonraker_url="http://h:7125",
    api_key=SecretStr("key"),
    capabilities=Capabilities(
        build_volume=BuildVolume(x=250, y=210, z=220),
        nozzle_diameter=0.4,
        material="PETG",
        max_extruder_temp=290,
        max_bed_temp=120,
    ),
)
DETECTED = {
    "build_volume": {"x": 220.0, "y": 220.0, "z": 250.0},
    "nozzle_diameter": 0.6,
    "max_extruder_temp": 280.0,
    "max_bed_temp": 110.0,
}
SPOOL = Spool(id=3, name="Black", material="PLA", color_hex="000000", remaining_g=412.5)
TOOLHEAD = {
    "position": [1.0, 2.0, 3.0, 0.0],
    "homed_axes": "xyz",
    "axis_minimum": [-5.0, -2.5, 0.0, 0.0],
}


def status(state: str, **more: Any) -> dict[str, Any]:
    return {
        "webhooks": {"state": "ready"},
        "print_stats": {"state": state, "filename": "cube.gcode" if state else ""},
        "extruder": {"temperature": 200.0, "target": 210.0},
        "heater_bed": {"temperature": 60.0, "target": 60.0},
        "toolhead": TOOLHEAD,
        **more,
    }


def online(klippy: str = "ready", state: str = "standby", **changes: Any) -> LivePrinter:
    base = LivePrinter(
        connection="online", klippy_state=klippy, status=status(state), limits="known"
    )
    return dataclasses.replace(base, **changes)


CASES: dict[str, LivePrinter] = {
    "ready idle": online(detected=DETECTED),
    "printing": online(state="printing", detected=DETECTED),
    "paused": online(state="paused", detected=DETECTED),
    "complete": online(state="complete", detected=DETECTED),
    "shut down mid-print": online("shutdown", "printing", klippy_message="MCU 'mcu' shutdown"),
    "error": online("error", "standby", detected=DETECTED),
    "startup": online("startup", "printing", detected=DETECTED),
    "disconnected": LivePrinter(connection="offline", connection_error="refused"),
    "connecting": LivePrinter(),
    "auth failed": LivePrinter(connection="auth_failed"),
    "with a spool": online(detected=DETECTED, spool=SPOOL, spoolman="active"),
    "a spool without material": online(spool=dataclasses.replace(SPOOL, material="")),
    "limits loading": online(limits="loading"),
    "limits unknown": online(limits="unknown", detected={"nozzle_diameter": 0.4}),
    "no axis minimum": online(status={**status("standby"), "toolhead": {"homed_axes": ""}}),
    "junk axis minimum": online(
        status={**status("standby"), "toolhead": {"axis_minimum": ["a", 0, 0]}}
    ),
}
CONFIGS = {"plain": PLAIN, "configured": CONFIGURED}


def checks() -> list[tuple[str, dict[str, Any]]]:
    """Every action, with parameters that reach the file, temperature and move rules."""
    meta = {"object_height": 240.0, "nozzle_diameter": 0.4, "filament_type": "PLA",
            "filament_weight_total": 500.0, "first_layer_extr_temp": 285.0}  # fmt: skip
    found: list[tuple[str, dict[str, Any]]] = [(action, {}) for action in ACTIONS]
    found += [
        ("start", {"filename": "cube.gcode", "_meta": meta}),
        ("upload", {"filename": "cube.gcode", "start": True, "_meta": meta}),
        ("upload", {"filename": "cube.gcode", "_meta": meta}),
        ("set_temperature", {"extruder": 285.0, "bed": 115.0}),
        ("gcode", {"script": "G1 X-4 Y-3 Z1\nM104 S300"}),
        ("gcode", {"script": "FIRMWARE_RESTART"}),
        ("gcode", {"script": "G28"}),
        ("home", {"axes": "xy"}),
    ]
    return found


def verdicts(printer: PrinterFacts) -> list[Any]:
    out: list[Any] = [allowed_actions(printer)]
    for action, params in checks():
        meta = params.get("_meta")
        given = {k: v for k, v in params.items() if k != "_meta"}
        for force in (False, True):
            out.append(validate(action, printer, params=given, file_meta=meta, force=force))
    return out


@pytest.mark.parametrize("config", CONFIGS.values(), ids=CONFIGS.keys())
@pytest.mark.parametrize("live", CASES.values(), ids=CASES.keys())
def test_the_facts_of_the_view_judge_as_the_live_facts(
    config: PrinterConfig, live: LivePrinter
) -> None:
    from_live = facts(config, live)
    from_view = facts_of_view(config, fuse(config, live))
    if live.klippy_state == "ready":
        assert from_view == from_live
    else:
        # fuse() blanks the job's state while Klippy is not ready; nothing else differs.
        assert from_view == dataclasses.replace(from_live, print_state="")
    assert verdicts(from_view) == verdicts(from_live)


def test_the_view_carries_klippers_axis_minimum() -> None:
    config = PLAIN
    assert fuse(config, online())["toolhead"]["axis_minimum"] == [-5.0, -2.5, 0.0]
    assert facts_of_view(config, fuse(config, online())).axis_minimum == (-5.0, -2.5, 0.0)
    junk = online(status={**status("standby"), "toolhead": {"axis_minimum": [1, None, 2]}})
    assert fuse(config, junk)["toolhead"]["axis_minimum"] is None


def test_the_spools_material_comes_before_printers_json() -> None:
    view = fuse(CONFIGURED, online(spool=SPOOL))
    read = facts_of_view(CONFIGURED, view)
    assert (read.material, read.filament_left_g) == ("PLA", 412.5)
    assert facts_of_view(CONFIGURED, fuse(CONFIGURED, online())).material == "PETG"
    assert facts_of_view(CONFIGURED, fuse(CONFIGURED, online())).filament_left_g is None


def test_printers_json_capabilities_win_over_klippys() -> None:
    read = facts_of_view(CONFIGURED, fuse(CONFIGURED, online(detected=DETECTED)))
    assert (read.build_volume, read.nozzle_diameter, read.max_bed_temp) == (
        (250, 210, 220),
        0.4,
        120,
    )
    assert read.limits == "known"
    detected = facts_of_view(PLAIN, fuse(PLAIN, online(detected=DETECTED)))
    assert (detected.build_volume, detected.nozzle_diameter) == ((220.0, 220.0, 250.0), 0.6)
