"""The last half hour of every printer's heaters, in memory: what the temperature graph of
a printer's detail view draws (``GET /api/printers/{id}/temperatures``).

Fed by the status the sessions already receive, never by a poll of its own. Moonraker
pushes only what changed (about four times a second), so each heater keeps at most one
sample per second, the latest value of that second, and a heater whose value did not change
sends nothing: a sample holds until the next one. A reader therefore gets the held values
repeated at "now", so a graph reaches the present; when the printer goes offline (or Klippy
stops) a gap ends the series (``None`` in JSON) and nothing is held across it.

Memory is fixed per heater: a ring of :data:`CAPACITY` samples, the time as float64 and the
values as float32 (about 30 KB a heater, 60 KB a printer).
"""

from __future__ import annotations

import math
import time
from array import array
from collections.abc import Callable, Mapping
from typing import Any, Final

HEATERS: Final = ("extruder", "heater_bed")
"""The heaters the sessions subscribe to (:mod:`kybercore.moonraker.client`)."""
WINDOW_SECONDS: Final = 30 * 60
STEP_SECONDS: Final = 1.0
CAPACITY: Final = WINDOW_SECONDS + 64
"""One sample a second for the window, plus room for the gaps of a flapping connection."""

Series = dict[str, list[Any]]
"""``{"t": [epoch s], "temperature": [°C or None], "target": [°C or None]}``."""


class _Ring:
    """One heater's samples, oldest first, in fixed arrays (no object per sample)."""

    __slots__ = ("count", "last", "second", "start", "target", "temperature", "times")

    def __init__(self) -> None:
        self.times = array("d", bytes(8 * CAPACITY))
        self.temperature = array("f", bytes(4 * CAPACITY))
        self.target = array("f", bytes(4 * CAPACITY))
        self.start = 0
        self.count = 0
        self.last = 0
        """Index of the newest sample (when ``count``)."""
        self.second = math.nan
        """``STEP_SECONDS`` step of the newest sample (NaN, equal to nothing, when empty)."""

    def _last(self) -> int:
        return self.last

    def put(self, at: float, temperature: float, target: float) -> None:
        """Record a sample; within the second of the last one it replaces that one."""
        second = at // STEP_SECONDS
        # Three updates in four land in the second of the one before: only overwrite.
        if second == self.second:
            last = self.last
            self.times[last], self.temperature[last], self.target[last] = (
                at, temperature, target,
            )  # fmt: skip
            return
        if self.count == CAPACITY:
            index = self.start
            self.start = (self.start + 1) % CAPACITY
        else:
            index = (self.start + self.count) % CAPACITY
            self.count += 1
        self.times[index], self.temperature[index], self.target[index] = at, temperature, target
        self.last, self.second = index, second

    def gap(self, at: float) -> None:
        """End the series here: what follows is not a continuation of what came before."""
        if self.count and not math.isnan(self.temperature[self._last()]):
            self.put(at, math.nan, math.nan)

    def since(self, first: float, now: float) -> Series:
        """The samples from ``first`` on, with the held values repeated at ``now``."""
        t: list[float] = []
        temps: list[float | None] = []
        targets: list[float | None] = []
        for i in range(self.count):
            index = (self.start + i) % CAPACITY
            at = self.times[index]
            if at < first:
                continue
            t.append(round(at, 3))
            temps.append(_value(self.temperature[index]))
            targets.append(_value(self.target[index]))
        if t and temps[-1] is not None and now - t[-1] >= STEP_SECONDS:
            t.append(round(now, 3))
            temps.append(temps[-1])
            targets.append(targets[-1])
        return {"t": t, "temperature": temps, "target": targets}


def _number(value: Any) -> bool:
    """An int or float (a bool is neither, whatever Python says)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _value(stored: float) -> float | None:
    return None if math.isnan(stored) else round(stored, 2)


class Temperatures:
    """Every printer's heater history for the last :data:`WINDOW_SECONDS`."""

    def __init__(self, clock: Callable[[], float] = time.time) -> None:
        self._clock = clock
        self._printers: dict[str, dict[str, _Ring]] = {}

    def feed(self, printer_id: str, status: Mapping[str, Any], changed: Mapping[str, Any]) -> None:
        """Sample the heaters that ``changed`` names (a delta, or a whole snapshot) from the
        printer's merged ``status``. Called for every status update: cheap when no heater
        is in it, and cheap when one is (exact type checks first: decoded JSON is floats)."""
        rings: dict[str, _Ring] | None = None
        now = 0.0
        for heater in HEATERS:
            if heater not in changed:
                continue
            fields = status.get(heater)
            if type(fields) is not dict and not isinstance(fields, Mapping):
                continue
            temperature: Any = fields.get("temperature")
            target: Any = fields.get("target")
            if type(temperature) is not float and not _number(temperature):
                continue
            if type(target) is not float and not _number(target):
                target = 0.0
            if rings is None:
                now = self._clock()
                rings = self._printers.get(printer_id)
                if rings is None:
                    rings = self._printers[printer_id] = {}
            ring = rings.get(heater)
            if ring is None:
                ring = rings[heater] = _Ring()
            ring.put(now, float(temperature), float(target))

    def gap(self, printer_id: str) -> None:
        """The printer stopped reporting (offline, Klippy not ready): hold nothing across."""
        now = self._clock()
        for ring in self._printers.get(printer_id, {}).values():
            ring.gap(now)

    def forget(self, printer_id: str) -> None:
        """Drop a removed printer's history."""
        self._printers.pop(printer_id, None)

    def series(self, printer_id: str, minutes: float = 30) -> dict[str, Series]:
        """The last ``minutes`` of each heater that reported, by heater name."""
        now = self._clock()
        first = now - min(minutes * 60, WINDOW_SECONDS)
        rings = self._printers.get(printer_id, {})
        return {heater: ring.since(first, now) for heater, ring in rings.items()}
