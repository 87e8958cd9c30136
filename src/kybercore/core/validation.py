"""Every rule that decides whether an action may go to a printer: pure functions, no I/O.

``validate(action, printer, params=..., file_meta=..., force=...)`` returns a ``Verdict``:
``ok``, ``warn`` (the UI asks the user to confirm) or ``block`` (refused; only the rules that
name ``force`` give way to it). Each ``Reason`` has a stable snake_case code, a category the
fleet service turns into an HTTP status (connection→503, state→409, limit and
compatibility→422) and a message in English and Spanish saying what is wrong and what to do.
All codes and messages are in :mod:`kybercore.core.messages`.

Why each file check is a block or a warning:

* **block** when the print or the machine is ruined for sure: the part is taller than the Z
  travel, the file was sliced for another nozzle size (every extrusion would be wrong), or
  it heats a heater past its max_temp (Klipper would shut down in the middle of heating).
* **warn** when the operator may know better: a filament type other than the one recorded
  as loaded (printers.json may be stale; some profiles print fine with a close material),
  and a file sliced for another printer model (clones and renamed profiles are common).
* A missing fact is never guessed: without the file's value, the loaded material or the
  max_temp the check is skipped; starting a file with no metadata at all is a warning.

Emergency stop needs only a connection and is never blocked by state. After a shutdown only
a firmware restart brings Klippy back: the MCU is shut down too, and a host restart would
leave Klippy in error. An upload without
``start`` only stores a file, so its file checks are warnings at most. A G-code script is
checked for what can be read from it; see :mod:`kybercore.core.gcode`.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any, Final

from kybercore.core.gcode import command_names, first_move_outside, gcode_temperatures
from kybercore.core.messages import Category, Level, Reason, reason
from kybercore.core.numbers import finite_number
from kybercore.core.spools import filament_needed_g

ACTIONS: Final = (
    "start", "pause", "resume", "cancel", "emergency_stop", "firmware_restart", "restart",
    "home", "set_temperature", "gcode", "upload",
)  # fmt: skip
MAX_SCRIPT_BYTES: Final = 64 * 1024

_SEVERITY: Final[dict[str, int]] = {"ok": 0, "warn": 1, "block": 2}
# Which category answers for a blocked verdict when several block (most urgent first).
_CATEGORY_ORDER: Final[tuple[Category, ...]] = (
    "connection", "state", "limit", "compatibility", "advisor",
)  # fmt: skip
_NOZZLE_TOLERANCE: Final = 0.01
# Klippy runs these even in shutdown/error (its "base" G-code handlers; M112 is ruled apart).
_GCODE_WHEN_DOWN: Final = frozenset({"RESTART", "FIRMWARE_RESTART", "STATUS", "HELP", "ECHO"})
_GCODE_RESTARTS: Final = ("SAVE_CONFIG", "FIRMWARE_RESTART", "RESTART")
_BUSY: Final = ("printing", "paused")
LIMITED_ACTIONS: Final = frozenset({"start", "upload", "set_temperature", "gcode"})
"""Actions judged against the printer's limits (max temperatures, volume, nozzle): refused
while the limits are not known. Never emergency stop, which must not wait for anything."""


@dataclass(frozen=True)
class Verdict:
    """The outcome of validation: the worst level among ``reasons`` ("ok" when none)."""

    level: Level
    reasons: tuple[Reason, ...]

    @classmethod
    def of(cls, reasons: Iterable[Reason]) -> Verdict:
        """Build a verdict whose level is the worst of ``reasons``."""
        found = tuple(reasons)
        worst: Level = max((r.level for r in found), key=_SEVERITY.__getitem__, default="ok")
        return cls(worst, found)

    @property
    def blocked(self) -> bool:
        """True when the action must not be sent."""
        return self.level == "block"

    @property
    def warnings(self) -> tuple[Reason, ...]:
        """The reasons the user should confirm before going on."""
        return tuple(r for r in self.reasons if r.level == "warn")

    @property
    def blocking_category(self) -> Category | None:
        """The most urgent category among blocking reasons (for the HTTP status), or None."""
        blocking = {r.category for r in self.reasons if r.level == "block"}
        return next((c for c in _CATEGORY_ORDER if c in blocking), None)


@dataclass(frozen=True)
class PrinterFacts:
    """What validation knows about one printer: live state plus configured capabilities.

    ``build_volume`` is the size of each axis and ``axis_minimum`` Klipper's position_min
    (0 when unknown). Whether the size was measured from 0 or from the minimum is not known,
    so moves are checked against the wider reading: ``minimum`` to
    ``max(size, minimum + size)``.
    """

    connection: str
    klippy_state: str
    print_state: str
    model: str = ""
    build_volume: tuple[float, float, float] | None = None
    axis_minimum: tuple[float, float, float] | None = None
    nozzle_diameter: float | None = None
    material: str | None = None
    max_extruder_temp: float | None = None
    max_bed_temp: float | None = None
    limits: str = "known"
    """Whether the limits above are all there is to know: ``known`` (from printers.json or
    Klippy's configfile), ``loading`` (being read after a connect) or ``unknown`` (the
    read failed; retried)."""
    filament_left_g: float | None = None
    """Grams left on the loaded Spoolman spool; None when no spool is known."""


def validate(
    action: str,
    printer: PrinterFacts,
    *,
    params: Mapping[str, Any] | None = None,
    file_meta: Mapping[str, Any] | None = None,
    force: bool = False,
) -> Verdict:
    """Check ``action`` on ``printer`` against every rule; never raises for bad input.

    ``params``: start/upload ``{"filename": str}`` (upload may add ``"start": True``);
    set_temperature ``{"extruder": float|None, "bed": float|None}``; gcode ``{"script": str}``;
    home ``{"axes": "xyz"}``. ``file_meta`` is Moonraker's ``/server/files/metadata`` result.
    Every reason is reported, not only the first, so a dry run shows all that is wrong.
    """
    params = params or {}
    if action not in ACTIONS:
        return Verdict.of([reason("unknown_action", action=action, valid=", ".join(ACTIONS))])
    connection = connection_reasons(printer)
    if connection:  # the rest of the facts are stale or unknown
        return Verdict.of(connection)
    reasons = _state_reasons(action, printer, params, force)
    if action in ("start", "upload"):
        reasons += _start_reasons(action, printer, params, file_meta)
    elif action == "set_temperature":
        reasons += _temperature_param_reasons(printer, params)
    elif action == "home":
        reasons += _home_param_reasons(params)
    elif action == "gcode":
        reasons += _gcode_reasons(printer, params.get("script"), force)
    return Verdict.of(reasons)


def allowed_actions(printer: PrinterFacts) -> dict[str, bool]:
    """Which actions connection and state allow now, for enabling buttons in the UI.

    Files, parameters and ``force`` are unknown here, so ``False`` means "blocked without
    force" and ``True`` still leaves room for a file or parameter check to block later.
    """
    if connection_reasons(printer):
        return dict.fromkeys(ACTIONS, False)
    return {
        action: not any(r.level == "block" for r in _state_reasons(action, printer, {}, False))
        for action in ACTIONS
    }


def filament_types(value: Any) -> tuple[str, ...]:
    """Upper-case filament types from Moonraker's ``filament_type``: ``"PLA"``, a JSON list
    such as ``'["PLA", "PETG"]'`` (multi-material files) or ``"PLA;PETG"``."""
    if not isinstance(value, str) or not value.strip():
        return ()
    items: list[Any] = []
    if value.strip().startswith("["):
        try:
            parsed = json.loads(value)
        except ValueError:
            parsed = None
        items = parsed if isinstance(parsed, list) else []
    if not items:
        items = re.split(r"[;,]", value)
    unique = dict.fromkeys(str(i).strip().strip('"').upper() for i in items)
    return tuple(t for t in unique if t)


# --- connection and state ----------------------------------------------------------------


def connection_reasons(printer: PrinterFacts) -> list[Reason]:
    """Why nothing can be sent to the printer now (disabled, connecting, offline...)."""
    if printer.connection == "online":
        return []
    if printer.connection == "disabled":
        return [reason("printer_disabled")]
    if printer.connection in ("connecting", "auth_failed"):
        return [reason(f"printer_{printer.connection}")]
    return [reason("printer_offline")]


def _state_reasons(
    action: str, printer: PrinterFacts, params: Mapping[str, Any], force: bool
) -> list[Reason]:
    """Rules on Klippy's state, the print state and whether the limits are known (file and
    parameters aside)."""
    reasons = _klippy_and_print_reasons(action, printer, params, force)
    if (
        printer.limits != "known"
        and _needs_limits(action, params)
        and not any(r.level == "block" for r in reasons)
    ):
        # Without them the max-temp, volume and nozzle checks would silently pass.
        reasons.append(reason(f"limits_{printer.limits}"))
    return reasons


def _needs_limits(action: str, params: Mapping[str, Any]) -> bool:
    if action not in LIMITED_ACTIONS or (action == "upload" and not params.get("start")):
        return False
    script = params.get("script")
    # A script of commands that move and heat nothing (STATUS, HELP...) needs no limits.
    names = command_names(script) if action == "gcode" and isinstance(script, str) else []
    return not names or not all(n in _GCODE_WHEN_DOWN for n in names)


def _klippy_and_print_reasons(
    action: str, printer: PrinterFacts, params: Mapping[str, Any], force: bool
) -> list[Reason]:
    if action == "emergency_stop" or (action == "upload" and not params.get("start")):
        return []  # e-stop must always go through; storing a file does not need Klippy
    klippy, state = printer.klippy_state, printer.print_state
    if klippy in ("shutdown", "error"):
        script = params.get("script")
        names = command_names(script) if action == "gcode" and isinstance(script, str) else []
        if klippy == "shutdown" and (action == "restart" or "RESTART" in names):
            # A shutdown stops the MCU too: a host restart cannot configure it again ("Can
            # not update MCU config as it is shutdown") and leaves Klippy in error.
            return [reason("restart_after_shutdown")]
        if action in ("firmware_restart", "restart") or (
            names and all(n in _GCODE_WHEN_DOWN for n in names)
        ):
            return []
        return [reason(f"klippy_{klippy}")]
    if klippy != "ready":
        return [reason("klippy_startup" if klippy == "startup" else "klippy_disconnected")]
    if action in ("start", "upload") and state in _BUSY:
        return [reason("print_in_progress")]
    if action == "pause" and state != "printing":
        return [reason("pause_not_printing")]
    if action == "resume" and state != "paused":
        return [reason("resume_not_paused")]
    if action == "cancel" and state not in _BUSY:
        return [reason("cancel_no_print")]
    if action == "home" and state in _BUSY:
        return [reason("home_while_printing")]
    if action in ("restart", "firmware_restart") and state in _BUSY:
        if force:
            return [reason("forced_during_print")]
        doing = ("Restarting Klipper", "Reiniciar Klipper") if action == "restart" else (
            "Restarting the firmware", "Reiniciar el firmware")  # fmt: skip
        return [reason("restart_while_printing", doing_en=doing[0], doing_es=doing[1])]
    return []


# --- starting a file -----------------------------------------------------------------------


def _start_reasons(
    action: str, printer: PrinterFacts, params: Mapping[str, Any], meta: Mapping[str, Any] | None
) -> list[Reason]:
    starts = action == "start" or bool(params.get("start"))
    reasons: list[Reason] = []
    filename = params.get("filename")
    if not isinstance(filename, str) or not filename.strip():
        reasons.append(reason("filename_missing"))
    if meta is None:
        return [*reasons, reason("file_metadata_missing")] if starts else reasons
    found = _file_reasons(printer, meta)
    if not starts:  # the file is only stored: say so now, block when it is started
        found = [replace(r, level="warn") if r.level == "block" else r for r in found]
    return reasons + found


def _file_reasons(printer: PrinterFacts, meta: Mapping[str, Any]) -> list[Reason]:
    """A sliced file (Moonraker's metadata) against one printer's capabilities."""
    reasons: list[Reason] = []
    height, volume = finite_number(meta.get("object_height")), printer.build_volume
    if height is not None and volume is not None and height > volume[2] + 1e-6:
        reasons.append(reason("file_too_tall", height=height, z=volume[2]))
    nozzle, ours = finite_number(meta.get("nozzle_diameter")), printer.nozzle_diameter
    if nozzle is not None and ours is not None and abs(nozzle - ours) > _NOZZLE_TOLERANCE:
        reasons.append(reason("nozzle_mismatch", file=nozzle, ours=ours))
    needed, left = filament_needed_g(meta), printer.filament_left_g
    if needed is not None and left is not None and needed > left:
        reasons.append(reason("not_enough_filament", needed=round(needed, 1), left=round(left, 1)))
    types, loaded = filament_types(meta.get("filament_type")), (printer.material or "").strip()
    if types and loaded and loaded.upper() not in types:
        reasons.append(reason("filament_mismatch", file=", ".join(types), loaded=loaded))
    for code, key, limit in (
        ("file_extruder_temp_over_max", "first_layer_extr_temp", printer.max_extruder_temp),
        ("file_bed_temp_over_max", "first_layer_bed_temp", printer.max_bed_temp),
    ):
        temp = finite_number(meta.get(key))
        if temp is not None and limit is not None and temp > limit:
            reasons.append(reason(code, temp=temp, limit=limit))
    sliced_for = meta.get("printer_model")
    if isinstance(sliced_for, str) and not _models_match(printer.model, sliced_for):
        reasons.append(
            reason("printer_model_mismatch", file=sliced_for.strip(), ours=printer.model.strip())
        )
    return reasons


def _models_match(ours: str, sliced_for: str) -> bool:
    """Unknown on either side counts as a match. "Prusa MK4" and "MK4" name the same
    machine, so containment matches too: only a clear difference warns."""
    a, b = _normal_model(ours), _normal_model(sliced_for)
    if not a or not b:
        return True
    return a == b or (min(len(a), len(b)) >= 3 and (a in b or b in a))


def _normal_model(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


# --- parameters of set_temperature and home ------------------------------------------------


def _temperature_param_reasons(printer: PrinterFacts, params: Mapping[str, Any]) -> list[Reason]:
    given = {h: params.get(h) for h in ("extruder", "bed") if params.get(h) is not None}
    if not given:
        return [reason("temperature_missing")]
    reasons: list[Reason] = []
    for heater, value in given.items():
        temp = finite_number(value) if isinstance(value, int | float) else None
        if temp is None or temp < 0:
            names = ("extruder", "el extrusor") if heater == "extruder" else ("bed", "la cama")
            reasons.append(reason("temperature_invalid", heater_en=names[0],
                                   heater_es=names[1], value=repr(value)))  # fmt: skip
            continue
        limit = printer.max_extruder_temp if heater == "extruder" else printer.max_bed_temp
        if limit is not None and temp > limit:
            reasons.append(reason(f"{heater}_temp_over_max", temp=temp, limit=limit))
    return reasons


def _home_param_reasons(params: Mapping[str, Any]) -> list[Reason]:
    axes = params.get("axes")
    if axes is None or (isinstance(axes, str) and set(axes.lower()) <= set("xyz")):
        return []
    return [reason("home_axes_invalid", axes=repr(axes))]


# --- G-code scripts ------------------------------------------------------------------------


def _gcode_reasons(printer: PrinterFacts, script: Any, force: bool) -> list[Reason]:
    if isinstance(script, str) and len(script.encode()) > MAX_SCRIPT_BYTES:
        return [reason("gcode_too_long", kib=str(len(script.encode()) // 1024))]
    names = command_names(script) if isinstance(script, str) else []
    if not isinstance(script, str) or not names:
        return [reason("gcode_empty")]
    reasons: list[Reason] = []
    if "M112" in names:
        reasons.append(reason("gcode_m112"))
    busy = printer.klippy_state == "ready" and printer.print_state in _BUSY
    restarts = " / ".join(n for n in _GCODE_RESTARTS if n in names)
    if busy and restarts:
        reasons.append(reason("forced_during_print") if force else
                       reason("gcode_restart_while_printing", commands=restarts))  # fmt: skip
    if busy and "G28" in names:
        reasons.append(reason("forced_during_print" if force else "gcode_home_while_printing"))
    for request in gcode_temperatures(script):
        limit = printer.max_extruder_temp if request.heater == "extruder" else printer.max_bed_temp
        if limit is not None and request.target > limit:
            line = f"{request.line} ({request.text})"
            code = f"gcode_{request.heater}_temp_over_max"
            reasons.append(reason(code, line=line, temp=request.target, limit=limit))
    if printer.build_volume is not None:
        low = printer.axis_minimum or (0.0, 0.0, 0.0)
        high = [max(s, lo + s) for lo, s in zip(low, printer.build_volume, strict=True)]
        move = first_move_outside(script, low, high)
        if move is not None:
            i = "XYZ".index(move.axis)
            line = f"{move.line} ({move.text})"
            reasons.append(reason("gcode_move_outside_volume", line=line, axis=move.axis,
                                   low=float(low[i]), high=float(high[i])))  # fmt: skip
    return reasons


# --- helpers -------------------------------------------------------------------------------
