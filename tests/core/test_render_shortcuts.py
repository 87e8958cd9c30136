"""The render's shortcuts (issue 20) give the very views the long way gave."""

from __future__ import annotations

import time

from bench.printer_model import FILENAME, SimPrinter

from kybercore.core.numbers import finite_number
from kybercore.core.progress import PrintMemory, estimate, track
from kybercore.core.view import LivePrinter, filament_runout, fuse, tracked
from kybercore.moonraker.objects import apply_status
from kybercore.registry.models import PrinterConfig

CONFIG = PrinterConfig(id="p1", name="P1", moonraker_url="http://127.0.0.1:1")


def printing() -> tuple[SimPrinter, LivePrinter]:
    sim = SimPrinter(7)
    live = LivePrinter(connection="online", klippy_state="ready", status=sim.status())
    live.file_meta, live.updated_at = sim.metadata(FILENAME), time.time()
    return sim, live


def test_ints_are_numbers_unless_past_floats_range() -> None:
    assert finite_number(4_523_117) == 4_523_117.0
    assert type(finite_number(3)) is float
    assert finite_number(10**400) is None
    assert finite_number(True) is None


def test_a_tracked_render_is_the_render_that_tracks_again() -> None:
    sim, live = printing()
    for _ in range(30):
        apply_status(live.status, sim.step())
        live.print_memory = tracked(live)
        assert fuse(CONFIG, live, tracked=True) == fuse(CONFIG, live)
        memory, meta = live.print_memory, live.file_meta
        assert estimate(memory, live.status, meta, 5.0, tracked=True) == estimate(
            memory, live.status, meta, 5.0
        )


def test_tracking_what_was_tracked_gives_the_same_memory() -> None:
    sim, live = printing()
    apply_status(live.status, sim.step())
    once = track(PrintMemory(), live.status, live.file_meta)
    assert track(once, live.status, live.file_meta) is once
    apply_status(live.status, sim.step())
    assert track(once, live.status, live.file_meta) is not once


def test_the_thumbnail_follows_a_new_metadata_object_and_a_new_file() -> None:
    _, live = printing()
    assert fuse(CONFIG, live)["job"]["thumbnail"] == ".thumbs/b.png"
    assert fuse(CONFIG, live)["job"]["thumbnail"] == ".thumbs/b.png"  # remembered
    live.file_meta = {**live.file_meta, "thumbnails": [{"width": 9, "relative_path": "t.png"}]}
    assert fuse(CONFIG, live)["job"]["thumbnail"] == "t.png"
    live.status["print_stats"]["filename"] = "queue/" + FILENAME
    live.file_meta = {**live.file_meta, "filename": "queue/" + FILENAME}
    assert fuse(CONFIG, live)["job"]["thumbnail"] == "queue/t.png"
    live.file_meta = None
    assert fuse(CONFIG, live)["job"]["thumbnail"] is None


def test_the_runout_follows_sensors_added_changed_and_a_new_status() -> None:
    sim, live = printing()
    assert fuse(CONFIG, live)["runout"] is False
    sensor = "filament_switch_sensor spool"
    apply_status(live.status, {sensor: {"filament_detected": True, "enabled": True}})
    assert fuse(CONFIG, live)["runout"] is False  # a new object: the names are found again
    apply_status(live.status, {sensor: {"filament_detected": False}})
    assert fuse(CONFIG, live)["runout"] is True
    apply_status(live.status, {sensor: {"enabled": False}})
    assert fuse(CONFIG, live)["runout"] is False
    live.status = {**sim.status(), "filament_motion_sensor m": {"filament_detected": False}}
    assert fuse(CONFIG, live)["runout"] is True  # a snapshot: another status object
    for _ in range(5):
        apply_status(live.status, sim.step())
        assert fuse(CONFIG, live)["runout"] is filament_runout(live.status) is True


def test_the_axis_minimum_shown_follows_each_list_received() -> None:
    _, live = printing()
    assert fuse(CONFIG, live)["toolhead"]["axis_minimum"] == [0.0, 0.0, -2.0]
    apply_status(live.status, {"toolhead": {"axis_minimum": [-5, 1.5, -1.0, 0.0]}})
    assert fuse(CONFIG, live)["toolhead"]["axis_minimum"] == [-5.0, 1.5, -1.0]
    apply_status(live.status, {"toolhead": {"axis_minimum": ["junk", 0.0, 0.0, 0.0]}})
    assert fuse(CONFIG, live)["toolhead"]["axis_minimum"] is None
    del live.status["toolhead"]["axis_minimum"]
    assert fuse(CONFIG, live)["toolhead"]["axis_minimum"] is None


def test_the_position_is_shown_only_when_every_value_is_a_number() -> None:
    _, live = printing()
    cases: list[tuple[object, object]] = [
        ([1.234, 2, 3.0, 4.0, 5.5], [1.23, 2.0, 3.0, 4.0]),
        ([1.0, "2", 3.0, 4.0], None),
        ([1.0, 2.0, 3.0, 4.0, None], None),  # junk past the 4 shown still makes it junk
        ([1.0, 2.0, [3.0], 4.0], None),
        ("1,2,3,4", None),
        ([], None),
    ]
    for position, shown in cases:
        live.status["toolhead"]["position"] = position
        assert fuse(CONFIG, live)["toolhead"]["position"] == shown, position
