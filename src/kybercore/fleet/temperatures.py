"""The last half hour of every printer's heaters, in memory: what the temperature graph of
a printer's detail view draws (``GET /api/printers/{id}/temperatures``).

Fed by the status the sessions already receive, never by a poll of its own. Moonraker
pushes only what changed (about four times a second), so each heater keeps at most one
sample per second, the latest value of that second, and a heater whose value did not change
sends nothing: a sample holds until the next one. A reader therefore gets the held values
repeated at "now", so a graph reaches the present; when the printer goes offline (or Klippy
stops) a gap ends the series (``None`` in JSON) and nothing is held across it.

Memory: a heater that reported keeps one slot per second of the window, the second's
number modulo :data:`CAPACITY` (so no time is stored), with both values in tenths of a
degree, the precision Klipper's ``M105`` and every dashboard show: 4 bytes a second, 7 KB a
heater, 14 KB a printer; a printer that never came online holds nothing.
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
CAPACITY: Final = WINDOW_SECONDS + 1
"""Slots a heater keeps: one a second for the window, both ends included."""

GAP: Final = -32768
"""The stored value of "no value": where a series ends (offline, Klippy not ready)."""
EMPTY: Final = -32767
"""The stored value of a second in which nothing came (the value held from before)."""

Series = dict[str, list[Any]]
"""``{"t": [epoch s], "temperature": [°C or None], "target": [°C or None]}``."""


class _Ring:
    """One heater's last :data:`CAPACITY` seconds: second ``n``'s latest values in slot
    ``n % CAPACITY`` of two fixed arrays (no object per sample, no time stored).

    The newest second's values are held as floats and stored only once a later second
    begins (or a reader asks): three updates in four land in the second of the one
    before, and each then costs two assignments."""

    __slots__ = ("held", "newest", "target", "temperature")

    def __init__(self) -> None:
        self.temperature = array("h", [EMPTY]) * CAPACITY
        self.target = array("h", [EMPTY]) * CAPACITY
        """Tenths of a degree; :data:`GAP` for no value, :data:`EMPTY` for no sample."""
        self.newest: int | None = None
        """The second of the newest sample."""
        self.held = (math.nan, math.nan)
        """The newest second's temperature and target, not stored yet."""

    def put(self, second: int, temperature: float, target: float) -> None:
        """Record a sample of ``second``; within the second of the last one it replaces
        that one."""
        newest = self.newest
        if second != newest:
            if newest is not None:
                if second < newest:
                    if second > newest - CAPACITY:  # the clock went back within the window
                        self._store(second, temperature, target)
                    return
                self.flush()
                if second > newest + 1:
                    self._skip(newest, second)
            self.newest = second
        self.held = (temperature, target)

    def flush(self) -> None:
        """Store the newest second's values."""
        if self.newest is not None:
            self._store(self.newest, *self.held)

    def _store(self, second: int, temperature: float, target: float) -> None:
        slot = second % CAPACITY
        self.temperature[slot] = _tenths(temperature)
        self.target[slot] = _tenths(target)

    def _skip(self, newest: int, second: int) -> None:
        """Empty the slots of the seconds between ``newest`` and ``second``: they still
        hold values from a lap of the ring ago."""
        for skipped in range(max(newest + 1, second - CAPACITY), second):
            self.temperature[skipped % CAPACITY] = EMPTY

    def gap(self, second: int) -> None:
        """End the series here: what follows is not a continuation of what came before."""
        if self.newest is not None and not math.isnan(self.held[0]):
            self.put(second, math.nan, math.nan)

    def since(self, first: float, now: float) -> Series:
        """The samples from ``first`` on, with the held values repeated at ``now``."""
        t: list[float] = []
        temps: list[float | None] = []
        targets: list[float | None] = []
        self.flush()
        newest = self.newest
        if newest is not None:
            start = max(newest - CAPACITY + 1, math.ceil(first / STEP_SECONDS))
            for second in range(start, newest + 1):
                slot = second % CAPACITY
                temperature = self.temperature[slot]
                if temperature == EMPTY:
                    continue
                t.append(second * STEP_SECONDS)
                temps.append(_degrees(temperature))
                targets.append(_degrees(self.target[slot]))
        if t and temps[-1] is not None and now - t[-1] >= STEP_SECONDS:
            t.append(round(now, 3))
            temps.append(temps[-1])
            targets.append(targets[-1])
        return {"t": t, "temperature": temps, "target": targets}


def _tenths(degrees: float) -> int:
    """A value as stored: tenths of a degree, :data:`GAP` for NaN, clamped to the range
    left by the two marks (a broken thermistor may read anything)."""
    if -3276.6 <= degrees <= 3276.7:  # NaN is not
        return round(degrees * 10)
    if math.isnan(degrees):
        return GAP
    return EMPTY + 1 if degrees < 0 else 32767


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
        second = 0
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
                second = self._second()
                rings = self._printers.get(printer_id)
                if rings is None:
                    rings = self._printers[printer_id] = {}
            ring = rings.get(heater)
            if ring is None:
                ring = rings[heater] = _Ring()
            ring.put(second, float(temperature), float(target))

    def gap(self, printer_id: str) -> None:
        """The printer stopped reporting (offline, Klippy not ready): hold nothing across."""
        second = self._second()
        for ring in self._printers.get(printer_id, {}).values():
            ring.gap(second)

    def _second(self) -> int:
        return int(self._clock() // STEP_SECONDS)

    def forget(self, printer_id: str) -> None:
        """Drop a removed printer's history."""
        self._printers.pop(printer_id, None)

    def series(self, printer_id: str, minutes: float = 30) -> dict[str, Series]:
        """The last ``minutes`` of each heater that reported, by heater name."""
        now = self._clock()
        first = now - min(minutes * 60, WINDOW_SECONDS)
        rings = self._printers.get(printer_id, {})
        return {heater: ring.since(first, now) for heater, ring in rings.items()}
