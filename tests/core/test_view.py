"""The pure fused view: what a printer looks like to the API and the browser."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import SecretStr

from kybercore.core.view import LivePrinter, detect_capabilities, diff, facts, fuse
from kybercore.errors import InvalidInput
from kybercore.fleet.actions import temperature_gcode
from kybercore.moonraker.objects import merge_status
from kybercore.registry.models import BuildVolume, Capabilities, PrinterConfig

CONFIG = PrinterConfig(
    id="p1",
    name="Printer 1",
    moonraker_url="http://127.0.0.1:7125",
    api_key=SecretStr("very-secret-key"),
    capabilities=Capabilities(material="PLA", max_bed_temp=100),
)

PRINTING: dict[str, dict[str, Any]] = {
    "webhooks": {"state": "ready"},
    "print_stats": {"state": "printing", "filename": "cube.gcode", "print_duration": 60.0},
    "display_status": {"progress": 0.25},
    "extruder": {"temperature": 204.96, "target": 205.0, "power": 0.42},
    "heater_bed": {"temperature": 60.04, "target": 60.0},
    "toolhead": {"position": [10.123, 20.0, 0.3, 100.0], "homed_axes": "xyz"},
}


def live(**changes: Any) -> LivePrinter:
    base = LivePrinter(connection="online", klippy_state="ready", status=PRINTING)
    for key, value in changes.items():
        setattr(base, key, value)
    return base


def test_fuse_merges_config_and_live_state_without_the_key() -> None:
    view = fuse(CONFIG, live(file_meta={"filename": "cube.gcode", "estimated_time": 300}))
    assert view["id"] == "p1"
    assert view["api_key_set"] is True
    assert "api_key" not in view
    assert "very-secret-key" not in repr(view)
    assert view["job"]["state"] == "printing"
    assert view["job"]["progress"] == 0.25
    assert view["job"]["estimated_time"] == 300
    assert view["extruder"] == {"temperature": 205.0, "target": 205.0, "power": 0.42}
    assert view["toolhead"]["position"] == [10.12, 20.0, 0.3, 100.0]
    assert view["actions"]["pause"] is True
    assert view["actions"]["start"] is False


def test_fuse_prefers_printers_json_and_falls_back_to_klippy() -> None:
    detected = {"build_volume": {"x": 220, "y": 220, "z": 250}, "max_bed_temp": 110}
    view = fuse(CONFIG, live(detected=detected))
    assert view["capabilities"]["build_volume"] == {"x": 220, "y": 220, "z": 250}
    assert view["capabilities"]["max_bed_temp"] == 100  # printers.json wins
    assert view["capabilities"]["material"] == "PLA"
    configured = CONFIG.model_copy(
        update={"capabilities": Capabilities(build_volume=BuildVolume(x=1, y=2, z=3))}
    )
    assert facts(configured, live(detected=detected)).build_volume == (1, 2, 3)


def test_a_shut_down_printer_has_no_job_state_and_only_restarts() -> None:
    view = fuse(CONFIG, live(klippy_state="shutdown"))
    assert view["job"]["state"] == ""
    assert view["actions"]["firmware_restart"] is True
    assert view["actions"]["start"] is False
    assert view["actions"]["pause"] is False


def test_metadata_of_another_file_is_not_used() -> None:
    view = fuse(CONFIG, live(file_meta={"filename": "other.gcode", "estimated_time": 999}))
    assert view["job"]["estimated_time"] is None


def test_largest_thumbnail_is_shown() -> None:
    thumbs = [
        {"width": 32, "relative_path": ".thumbs/cube-32x32.png"},
        {"width": 300, "relative_path": ".thumbs/cube-300x300.png"},
    ]
    view = fuse(CONFIG, live(file_meta={"filename": "cube.gcode", "thumbnails": thumbs}))
    assert view["job"]["thumbnail"] == ".thumbs/cube-300x300.png"


def test_a_thumbnail_of_a_file_in_a_folder_is_given_under_gcodes() -> None:
    name = "kybercore/j1-c1-a1-cube.gcode"
    status = {**PRINTING, "print_stats": {**PRINTING["print_stats"], "filename": name}}
    thumbs = [{"width": 300, "relative_path": ".thumbs/j1-c1-a1-cube-300x300.png"}]
    view = fuse(CONFIG, live(status=status, file_meta={"filename": name, "thumbnails": thumbs}))
    assert view["job"]["thumbnail"] == "kybercore/.thumbs/j1-c1-a1-cube-300x300.png"


def test_diff_sends_only_what_changed() -> None:
    old = fuse(CONFIG, live())
    status = merge_status(PRINTING, {"extruder": {"temperature": 210.0}})
    new = fuse(CONFIG, live(status=status))
    assert diff(old, new) == {"extruder": {"temperature": 210.0}}
    assert diff(new, new) == {}


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.text(max_size=5),
    lambda children: (
        st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=3), children, max_size=3)
    ),
    max_leaves=10,
)
views = st.dictionaries(st.text(max_size=4), json_values, max_size=5)


@given(views, views)
def test_applying_the_diff_gives_the_new_view_when_keys_are_kept(
    old: dict[str, Any], new: dict[str, Any]
) -> None:
    # Views never lose keys, so compare on a "new" that keeps every key of "old".
    new = _keep_keys(old, new)
    # As in a delta frame: {printer id: patch}, applied with Moonraker's merge rules.
    assert merge_status({"p1": old}, {"p1": diff(old, new)}) == {"p1": new}


def _keep_keys(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    out = dict(old)
    for key, value in new.items():
        if isinstance(value, dict) and isinstance(old.get(key), dict):
            out[key] = _keep_keys(old[key], value)
        else:
            out[key] = value
    return out


def test_detect_capabilities_from_configfile() -> None:
    settings = {
        "stepper_x": {"position_max": 220.0},
        "stepper_y": {"position_max": 230.0},
        "stepper_z": {"position_max": 250.0},
        "extruder": {"nozzle_diameter": 0.4, "max_temp": 280.0},
        "heater_bed": {"max_temp": 110.0},
    }
    assert detect_capabilities(settings) == {
        "build_volume": {"x": 220.0, "y": 230.0, "z": 250.0},
        "nozzle_diameter": 0.4,
        "max_extruder_temp": 280.0,
        "max_bed_temp": 110.0,
    }
    assert detect_capabilities({}) == {}


def test_temperature_gcode() -> None:
    assert temperature_gcode({"extruder": 200, "bed": 60.5}) == "M104 S200\nM140 S60.5"
    assert temperature_gcode({"bed": 0}) == "M140 S0"
    with pytest.raises(InvalidInput):
        temperature_gcode({})


def test_what_fuse_remembers_per_config_follows_the_live_state() -> None:
    # fuse() keeps derived values per config object; they must follow the same printer's
    # live state as it changes in place, as the fleet service changes it.
    printer = live(detected={})
    assert fuse(CONFIG, printer)["actions"]["pause"] is True
    printer.status = merge_status(printer.status, {"print_stats": {"state": "paused"}})
    paused = fuse(CONFIG, printer)["actions"]
    assert (paused["pause"], paused["resume"]) == (False, True)
    printer.klippy_state = "shutdown"
    assert fuse(CONFIG, printer)["actions"]["resume"] is False
    printer.klippy_state = "ready"
    assert fuse(CONFIG, printer)["capabilities"]["nozzle_diameter"] is None
    printer.detected = {"nozzle_diameter": 0.6}
    assert fuse(CONFIG, printer)["capabilities"]["nozzle_diameter"] == 0.6
    assert facts(CONFIG, printer).nozzle_diameter == 0.6
