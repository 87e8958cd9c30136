"""The last half hour of every printer's heaters, in memory: what the temperature graph of
a printer's detail view draws (``GET /api/printers/{id}/temperatures``).

Fed by the status the sessions already receive, never by a poll of its own. Moonraker
pushes only what changed (about four times a second), so each heater keeps at most one
sample per second, the latest value of that second, and a heater whose value did not change
sends nothing: a sample holds until the next one. A reader therefore gets the held values
repeated at "now", so a graph reaches the present; when the printer goes offline (or Klippy
stops) a gap ends the series (``None`` in JSON) and nothing is held across it.

Memory grows with the history and stops at a ring of :data:`CAPACITY` samples per heater,
8 bytes a sample: the time in tenths of a second since the heater's first sample, and both
values in tenths of a degree, the precision Klipper's ``M105`` and every dashboard show
(15 KB a heater, 30 KB a printer once it has reported for half an hour; a printer that never
came online holds nothing).
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

GAP: Final = -32768
"""The stored value of "no value": where a series ends (offline, Klippy not ready)."""

Series = dict[str, list[Any]]
"""``{"t": [epoch s], "temperature": [°C or None], "target": [°C or None]}``."""


class _Ring:
    """One heater's samples, oldest first, in compact arrays (no object per sample) that grow
    until they hold :data:`CAPACITY` samples, then wrap."""

    __slots__ = ("count", "last", "origin", "second", "start", "target", "temperature", "times")

    def __init__(self, origin: float) -> None:
        self.origin = origin
        """The time of the first sample: ``times`` counts tenths of a second from it (signed:
        a clock set back gives negative counts, not an error)."""
        self.times = array("i")
        self.temperature = array("h")
        self.target = array("h")
        """Tenths of a degree; :data:`GAP` for no value."""
        self.start = 0
        self.count = 0
        self.last = 0
        """Index of the newest sample (when ``count``)."""
        self.second = math.nan
        """``STEP_SECONDS`` step of the newest sample (NaN, equal to nothing, when empty)."""

    def put(self, at: float, temperature: float, target: float) -> None:
        """Record a sample; within the second of the last one it replaces that one."""
        second = at // STEP_SECONDS
        tenths = round((at - self.origin) * 10)
        temperature_, target_ = _tenths(temperature), _tenths(target)
        # Three updates in four land in the second of the one before: only overwrite.
        if second == self.second:
            last = self.last
            self.times[last], self.temperature[last], self.target[last] = (
                tenths, temperature_, target_,
            )  # fmt: skip
            return
        if self.count < CAPACITY:
            index = self.count
            self.times.append(tenths)
            self.temperature.append(temperature_)
            self.target.append(target_)
            self.count += 1
        else:
            index = self.start
            self.start = (self.start + 1) % CAPACITY
            self.times[index], self.temperature[index], self.target[index] = (
                tenths, temperature_, target_,
            )  # fmt: skip
        self.last, self.second = index, second

    def at(self, index: int) -> tuple[float, float | None, float | None]:
        """The sample at ``index``: its time (epoch s), temperature and target (None: a gap)."""
        return (
            self.origin + self.times[index] / 10,
            _degrees(self.temperature[index]),
            _degrees(self.target[index]),
        )

    def gap(self, at: float) -> None:
        """End the series here: what follows is not a continuation of what came before."""
        if self.count and self.temperature[self.last] != GAP:
            self.put(at, math.nan, math.nan)

    def since(self, first: float, now: float) -> Series:
        """The samples from ``first`` on, with the held values repeated at ``now``."""
        t: list[float] = []
        temps: list[float | None] = []
        targets: list[float | None] = []
        for i in range(self.count):
            at, temperature, target = self.at((self.start + i) % CAPACITY)
            if at < first:
                continue
            t.append(round(at, 1))
            temps.append(temperature)
            targets.append(target)
        if t and temps[-1] is not None and now - t[-1] >= STEP_SECONDS:
            t.append(round(now, 3))
            temps.append(temps[-1])
            targets.append(targets[-1])
        return {"t": t, "temperature": temps, "target": targets}


def _tenths(degrees: float) -> int:
    """A value as stored: tenths of a degree, :data:`GAP` for NaN, clamped to the array's
    range (a broken thermistor may read anything)."""
    if math.isnan(degrees):
        return GAP
    return max(-32767, min(32767, round(degrees * 10)))


def _degrees(stored: int) -> float | None:
    return None if stored == GAP else stored / 10


def _number(value: Any) -> bool:
    """An int or float (a bool is neither, whatever Python says)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


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
                ring = rings[heater] = _Ring(now)
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
