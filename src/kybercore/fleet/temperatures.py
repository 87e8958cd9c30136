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

    __slots__ = ("count", "start", "target", "temperature", "times")

    def __init__(self) -> None:
        self.times = array("d", bytes(8 * CAPACITY))
        self.temperature = array("f", bytes(4 * CAPACITY))
        self.target = array("f", bytes(4 * CAPACITY))
        self.start = 0
        self.count = 0

    def _last(self) -> int:
        return (self.start + self.count - 1) % CAPACITY

    def put(self, at: float, temperature: float, target: float) -> None:
        """Record a sample; within the second of the last one it replaces that one."""
        if self.count:
            last = self._last()
            if at // STEP_SECONDS == self.times[last] // STEP_SECONDS:
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
        is in it."""
        heaters = [h for h in HEATERS if h in changed]
        if not heaters:
            return
        now = self._clock()
        rings = self._printers.setdefault(printer_id, {})
        for heater in heaters:
            fields = status.get(heater)
            if not isinstance(fields, Mapping):
                continue
            temperature, target = fields.get("temperature"), fields.get("target")
            if not isinstance(temperature, int | float) or isinstance(temperature, bool):
                continue
            if not isinstance(target, int | float) or isinstance(target, bool):
                target = 0.0
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
