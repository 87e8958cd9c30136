"""How far a print is and when it will be done, as Mainsail and Fluidd reckon it.

Progress is the file position within the G-code proper: Moonraker's metadata gives the byte
of the first command (``gcode_start_byte``) and the end of the last (``gcode_end_byte``), so
thumbnails in the header and the slicer's settings block at the end do not count (Mainsail's
"file-relative" progress). The slicer's ``M73`` steps (``display_status.progress``) are used
only when Klippy's virtual SD card says nothing: they move in steps of 10 %, and Klippy keeps
the last one while the file position moves on.

Time left blends, like Mainsail's estimates:

- *file*: the pace measured so far, ``print_duration`` per fraction of the file printed;
- *filament*: the same pace measured in filament, ``filament_used`` of ``filament_total``;
- *slicer*: the slicer's ``estimated_time`` for the part not printed yet.

Klippy counts ``print_duration`` from the first extrusion (heating, homing and pauses
excluded), so the measured pace needs no correction for the heating; until that first
extrusion the time left is unknown (``None``, "—" on screen), not "0 s".

Pure functions: the view keeps a :class:`PrintMemory` per printer (the fleet layer stores
what :func:`track` returns and passes it back), which is what keeps the progress of a print
from going backwards whatever Klippy reports.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

from kybercore.core.numbers import finite_number

BUSY: Final = ("printing", "paused")

PACE_TRUSTED: Final = 0.2
"""Fraction of the file after which the measured pace alone gives the time left; before
that the slicer's estimate weighs in, less and less (early layers are slow, and a few
seconds of pace say little)."""

PACE_MIN: Final = 0.01
"""Without a slicer estimate, the pace says nothing before this fraction is printed."""

EXTRUDED: Final = 1e-3
"""``print_duration`` (s) above which the print has extruded: Klippy computes it as a
difference of times, which need not be exactly 0 before the first extrusion."""

RESTART_SLACK: Final = 2.0
"""Seconds ``print_duration`` may seem to go back (rounding, a late push) before a drop
means a new print of the same file."""


@dataclass(frozen=True, slots=True)
class PrintMemory:
    """What the view remembers of a printer's current (or last) print between updates."""

    filename: str = ""
    state: str = ""
    duration: float = 0.0
    """``print_duration`` at the last update."""
    progress: float = 0.0
    """The highest progress shown for this print: what is shown never goes below it."""
    heating_seen: bool = False
    """The print was seen busy before its first extrusion."""
    extruding_from: float | None = None
    """Progress at the last update before the first extrusion, if the print was followed
    from before it (else the start G-code's share of the file is unknown and taken as 0):
    the pace counts from there, as ``print_duration`` does."""


@dataclass(frozen=True, slots=True)
class Estimate:
    """Progress and time left as the view shows them."""

    progress: float
    """0 to 1, never lower than shown before during the same print."""
    eta_seconds: float | None
    """Seconds left; None unless printing or paused, and until extrusion starts."""
    eta_at: float | None
    """When the print will be done (Unix seconds), from ``now`` and ``eta_seconds``."""


def _obj(status: Mapping[str, Any], name: str) -> Mapping[str, Any]:
    value = status.get(name)
    # Exact dicts first (decoded JSON): the ABC check costs more than the rest of a call.
    return value if type(value) is dict or isinstance(value, Mapping) else {}


def _clamp(value: float) -> float:
    return min(max(value, 0.0), 1.0)


def meta_pending(meta: Mapping[str, Any] | None) -> bool:
    """True while the file's metadata is not read yet: the fleet first records only the
    file's name (``{"filename": ...}``), then Moonraker's answer or its failure."""
    return not meta or meta.keys() <= {"filename"}


def gcode_bytes(meta: Mapping[str, Any]) -> tuple[float, float] | None:
    """``(gcode_start_byte, gcode_end_byte)`` when the metadata gives a usable range."""
    start = finite_number(meta.get("gcode_start_byte"))
    end = finite_number(meta.get("gcode_end_byte"))
    if start is None or end is None or start < 0 or end <= start:
        return None
    return start, end


def file_progress(status: Mapping[str, Any], meta: Mapping[str, Any] | None) -> float | None:
    """How far Klippy is in the file, 0 to 1; None while the metadata is being read (the
    fraction of the whole file would then jump back once the G-code's range is known)."""
    if meta is None or meta_pending(meta):
        return None
    sdcard = _obj(status, "virtual_sdcard")
    position = finite_number(sdcard.get("file_position"))
    span = gcode_bytes(meta)
    if span is not None and position is not None:
        start, end = span
        return _clamp((position - start) / (end - start))
    absolute = finite_number(sdcard.get("progress"))
    loaded = (finite_number(sdcard.get("file_size")) or 0) > 0
    if absolute is not None and (loaded or absolute > 0):
        return _clamp(absolute)
    return _clamp(finite_number(_obj(status, "display_status").get("progress")) or 0.0)


def track(
    memory: PrintMemory, status: Mapping[str, Any], meta: Mapping[str, Any] | None
) -> PrintMemory:
    """The memory after an update of ``status`` (and of the file's metadata ``meta``).

    Idempotent: tracking the same update twice changes nothing, so the view may track
    whenever it renders."""
    stats = _obj(status, "print_stats")
    state = str(stats.get("state") or "")
    filename = str(stats.get("filename") or "")
    duration = finite_number(stats.get("print_duration")) or 0.0
    busy = state in BUSY
    new_print = busy and (
        memory.state not in BUSY
        or memory.filename != filename
        or duration + RESTART_SLACK < memory.duration
    )
    if new_print or memory.filename != filename:
        memory = PrintMemory(filename=filename)
    raw = file_progress(status, meta)
    progress = memory.progress if raw is None else max(memory.progress, raw)
    heating_seen = memory.heating_seen or (busy and duration <= EXTRUDED)
    extruding_from = memory.extruding_from
    if extruding_from is None and busy and duration > EXTRUDED:
        # The last progress seen before: a little early (homing, the prime line), never
        # late, however long the gap between the updates.
        extruding_from = memory.progress if memory.heating_seen else 0.0
    if (filename, state, duration, progress, heating_seen, extruding_from) == (
        memory.filename,
        memory.state,
        memory.duration,
        memory.progress,
        memory.heating_seen,
        memory.extruding_from,
    ):
        # Tracked already (estimate() tracks what the fleet tracked just before): the
        # same memory, not an equal copy (a frozen dataclass costs a microsecond to build).
        return memory
    return PrintMemory(filename, state, duration, progress, heating_seen, extruding_from)


def estimate(
    memory: PrintMemory,
    status: Mapping[str, Any],
    meta: Mapping[str, Any] | None,
    now: float,
    *,
    tracked: bool = False,
) -> Estimate:
    """Progress and time left after this update; ``memory`` is what :func:`track` gave
    before (it is tracked again here, which changes nothing when it already saw this
    update). ``now``: the time of the update, Unix seconds. ``tracked``: ``memory`` is
    :func:`track`'s answer for this very status and metadata, so tracking it again is
    skipped (the fleet tracks before every render; a second pass was a tenth of it)."""
    if not tracked:
        memory = track(memory, status, meta)
    left = _seconds_left(memory, status, meta or {})
    eta_at = now + left if left is not None and now > 0 else None
    return Estimate(memory.progress, left, eta_at)


def _seconds_left(
    memory: PrintMemory, status: Mapping[str, Any], meta: Mapping[str, Any]
) -> float | None:
    if memory.state not in BUSY or memory.duration <= EXTRUDED or meta_pending(meta):
        return None
    span = gcode_bytes(meta)
    position = finite_number(_obj(status, "virtual_sdcard").get("file_position"))
    if span is not None and position is not None and position < span[0]:
        return None  # still in the header: nothing of the G-code has run
    progress, duration = memory.progress, memory.duration
    if progress >= 1:
        return 0.0
    done = progress - (memory.extruding_from or 0.0)
    paces = []
    if done > 0:
        paces.append(duration / done * (1 - progress))  # "file"
    used = finite_number(_obj(status, "print_stats").get("filament_used")) or 0.0
    total = finite_number(meta.get("filament_total")) or 0.0
    if 0 < used < total:
        paces.append(duration * total / used - duration)  # "filament"
    estimated = finite_number(meta.get("estimated_time")) or 0.0
    by_slicer = estimated * (1 - progress) if estimated > 0 else None  # "slicer"
    paces = [pace for pace in paces if math.isfinite(pace)]  # a vanishing fraction done
    if not paces:
        return by_slicer
    by_pace = sum(paces) / len(paces)
    if by_slicer is None:
        return by_pace if done >= PACE_MIN and math.isfinite(by_pace) else None
    weight = min(max(done, 0.0) / PACE_TRUSTED, 1.0)
    left = by_slicer * (1 - weight) + by_pace * weight
    return left if math.isfinite(left) else by_slicer
