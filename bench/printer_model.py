"""The simulated printer behind each load-generator endpoint: plain data, no I/O.

Every printer is mid-print. Each :meth:`SimPrinter.step` is one Moonraker
``notify_status_update`` at 4 Hz: temperatures jitter, the toolhead moves, progress grows.

**How latency is matched to its source.** KyberCore does not forward Moonraker's
``eventtime``, so the source timestamp travels as a sequence number inside a field it does
forward unchanged: ``print_stats.print_duration`` is ``base + seq`` (whole seconds), and the
fused view shows it as ``job.print_duration`` (rounded to whole seconds, so exact). The load
generator records when it sent each ``seq``; a browser client records when it saw each
value; the harness joins the two. The field changes on every update in real Klipper too, so
no extra traffic is created for the measurement. Simulated print time therefore runs 4x
faster than wall time (one second per update); nothing in KyberCore depends on that pace.
"""

from __future__ import annotations

import math
import random
from typing import Any, Final

Status = dict[str, dict[str, Any]]

UPDATES_PER_SECOND: Final = 4
FILENAME: Final = "benchy_0.2mm_PLA.gcode"
ESTIMATED_TIME: Final = 7_200.0
FILE_SIZE: Final = 4_523_117
# Print durations start here plus the printer's index, so values differ between printers.
BASE_DURATION: Final = 600


class SimPrinter:
    """One printer's live state and the deltas it emits."""

    def __init__(self, index: int) -> None:
        self.index = index
        self.seq = 0
        self.base = BASE_DURATION + index % 3_600
        self.state = "printing"
        self._random = random.Random(index)
        self._changes: Status = {}
        self._status: Status = {
            "webhooks": {"state": "ready", "state_message": "Printer is ready"},
            "print_stats": {
                "filename": FILENAME,
                "state": "printing",
                "message": "",
                "print_duration": float(self.base),
                "total_duration": float(self.base) + 12.0,
                "filament_used": 0.0,
                "info": {"current_layer": 1, "total_layer": 240},
            },
            "virtual_sdcard": {
                "progress": 0.0,
                "is_active": True,
                "file_position": 0,
                "file_size": FILE_SIZE,
            },
            "display_status": {"progress": 0.0, "message": ""},
            "toolhead": {
                "position": [120.0, 120.0, 0.2, 0.0],
                "homed_axes": "xyz",
                "axis_minimum": [0.0, 0.0, -2.0, 0.0],
                "axis_maximum": [250.0, 250.0, 230.0, 0.0],
                "status": "Ready",
            },
            "extruder": {"temperature": 215.0, "target": 215.0, "power": 0.45},
            "heater_bed": {"temperature": 60.0, "target": 60.0, "power": 0.3},
            "fan": {"speed": 1.0},
            "gcode_move": {"speed_factor": 1.0, "extrude_factor": 1.0},
            "idle_timeout": {"state": "Printing"},
        }
        self._advance()

    @property
    def print_duration(self) -> float:
        """The value that encodes :attr:`seq` (see the module docstring)."""
        return float(self.base + self.seq)

    def status(self, objects: dict[str, list[str] | None] | None = None) -> Status:
        """The current state of ``objects`` (all of them when None), Moonraker-style:
        unknown objects are left out, a field list narrows an object."""
        if objects is None:
            return {name: dict(fields) for name, fields in self._status.items()}
        picked: Status = {}
        for name, wanted in objects.items():
            fields = self._status.get(name)
            if fields is None:
                continue
            picked[name] = {k: v for k, v in fields.items() if not wanted or k in wanted}
        return picked

    def step(self) -> Status:
        """One update: the fields that changed. While printing, ``seq`` grows by one; a
        paused or cancelled printer only reports its heaters (and a state change once)."""
        changes, self._changes = self._changes, {}
        if self.state == "printing":
            self.seq += 1
            delta = self._advance()
        else:
            delta = self._heaters()
        for name, fields in changes.items():
            delta.setdefault(name, {}).update(fields)
        return delta

    def _heaters(self) -> Status:
        rnd = self._random
        delta: Status = {
            "extruder": {"temperature": round(215.0 + rnd.uniform(-0.6, 0.6), 2)},
            "heater_bed": {"temperature": round(60.0 + rnd.uniform(-0.2, 0.2), 2)},
        }
        for name, fields in delta.items():
            self._status[name].update(fields)
        return delta

    def _advance(self) -> Status:
        rnd = self._random
        duration = self.print_duration
        progress = min(duration / ESTIMATED_TIME, 0.99)
        angle = self.seq / 8.0
        delta: Status = {
            "print_stats": {
                "print_duration": duration,
                "total_duration": duration + 12.0,
                "filament_used": round(duration * 1.7, 3),
            },
            "virtual_sdcard": {"progress": progress, "file_position": int(progress * FILE_SIZE)},
            "display_status": {"progress": progress},
            "toolhead": {
                "position": [
                    round(120.0 + 40.0 * math.cos(angle), 3),
                    round(120.0 + 40.0 * math.sin(angle), 3),
                    round(0.2 + progress * 48.0, 2),
                    round(duration * 0.9, 3),
                ]
            },
            "extruder": {
                "temperature": round(215.0 + rnd.uniform(-0.6, 0.6), 2),
                "power": round(rnd.uniform(0.3, 0.6), 3),
            },
            "heater_bed": {
                "temperature": round(60.0 + rnd.uniform(-0.2, 0.2), 2),
                "power": round(rnd.uniform(0.2, 0.4), 3),
            },
        }
        for name, fields in delta.items():
            self._status[name].update(fields)
        return delta

    def act(self, action: str) -> None:
        """What a print action does; the change goes out with the next update."""
        states = {"pause": "paused", "resume": "printing", "cancel": "cancelled"}
        self.state = states.get(action, "printing" if action == "start" else self.state)
        idle = "Printing" if self.state == "printing" else "Ready"
        self._changes = {"print_stats": {"state": self.state}, "idle_timeout": {"state": idle}}
        for name, fields in self._changes.items():
            self._status[name].update(fields)

    def metadata(self, filename: str) -> dict[str, Any]:
        """``/server/files/metadata`` for the file being printed."""
        return {
            "filename": filename,
            "size": FILE_SIZE,
            "modified": 1_763_700_000.0,
            "slicer": "PrusaSlicer",
            "slicer_version": "2.8.1",
            "estimated_time": ESTIMATED_TIME,
            "nozzle_diameter": 0.4,
            "layer_height": 0.2,
            "first_layer_height": 0.2,
            "first_layer_extr_temp": 215.0,
            "first_layer_bed_temp": 60.0,
            "filament_type": "PLA",
            "filament_total": 4_120.5,
            "object_height": 48.0,
            "thumbnails": [
                {"width": 32, "height": 32, "size": 1_210, "relative_path": ".thumbs/b-32.png"},
                {"width": 300, "height": 300, "size": 18_422, "relative_path": ".thumbs/b.png"},
            ],
        }


def configfile_settings() -> dict[str, Any]:
    """The part of Klippy's ``configfile.settings`` KyberCore reads once per printer."""
    return {
        "stepper_x": {"position_max": 250.0},
        "stepper_y": {"position_max": 250.0},
        "stepper_z": {"position_max": 230.0},
        "extruder": {"nozzle_diameter": 0.4, "max_temp": 300.0},
        "heater_bed": {"max_temp": 120.0},
    }
