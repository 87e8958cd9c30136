"""What each action does on Moonraker, and how its outcome or refusal is reported.

:mod:`kybercore.core.validation` decides whether an action may run; this module turns a
verdict into the right typed error, runs the action on a :class:`MoonrakerClient`, and
describes the outcome. The fleet service ties them together.
"""

from __future__ import annotations

import re
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from kybercore.core.messages import Reason
from kybercore.core.validation import Verdict
from kybercore.errors import (
    ActionRejected,
    InvalidInput,
    KyberCoreError,
    PrinterAuthFailed,
    PrinterUnreachable,
)
from kybercore.moonraker.client import FLEET_OBJECTS, MoonrakerClient


@dataclass
class ActionOutcome:
    """What happened when an action ran on one printer: done, or the error that stopped it."""

    printer_id: str
    action: str
    message: str
    error: KyberCoreError | None = None
    reasons: list[dict[str, str]] = field(default_factory=list)
    start: ActionOutcome | None = None
    """After an upload asked to start the file: that start, done or refused (the file is
    stored either way)."""
    response: list[str] = field(default_factory=list)
    """A console G-code's response lines from Klipper, in order (empty for the rest)."""

    @property
    def ok(self) -> bool:
        """True when the action was done."""
        return self.error is None

    @property
    def code(self) -> str:
        """``ok``, or the error's stable code."""
        return "ok" if self.error is None else self.error.code


def reason_dict(reason: Reason) -> dict[str, str]:
    """A validation reason as the API and the browser see it."""
    return {
        "code": reason.code,
        "level": reason.level,
        "category": reason.category,
        "en": reason.en,
        "es": reason.es,
    }


def raise_if_blocked(verdict: Verdict, printer_id: str) -> None:
    """Turn a blocking verdict into the error its category calls for."""
    blocking = [r for r in verdict.reasons if r.level == "block"]
    if not blocking:
        return
    message = f"{printer_id}: " + " ".join(r.en for r in blocking)
    category = verdict.blocking_category
    reasons = [reason_dict(r) for r in verdict.reasons]
    if category == "connection":
        auth = any(r.code == "printer_auth_failed" for r in blocking)
        raise (PrinterAuthFailed if auth else PrinterUnreachable)(message, reasons=reasons)
    if category in ("limit", "compatibility"):
        raise InvalidInput(message, reasons=reasons)
    raise ActionRejected(message, code=blocking[0].code, reasons=reasons)


def require_confirmation(verdict: Verdict, confirm: bool) -> list[dict[str, str]]:
    """The verdict's warnings; refused unless the user confirmed them."""
    warnings = [reason_dict(r) for r in verdict.reasons if r.level == "warn"]
    if warnings and not confirm:
        raise ActionRejected(
            "This action needs confirmation: "
            + " ".join(w["en"] for w in warnings)
            + " Send it again with confirm=true to go ahead.",
            code="confirmation_required",
            reasons=warnings,
        )
    return warnings


def failed_outcome(printer_id: str, action: str, exc: KyberCoreError) -> ActionOutcome:
    """The outcome of an action that raised ``exc``."""
    return ActionOutcome(printer_id, action, exc.message, exc, list(exc.reasons))


async def execute(client: MoonrakerClient, action: str, params: Mapping[str, Any]) -> list[str]:
    """Run a validated action on Moonraker; returns once Moonraker has done it, with
    Klipper's response lines for a console G-code (none for the other actions)."""
    simple: dict[str, Callable[[], Awaitable[None]]] = {
        "pause": client.print_pause,
        "resume": client.print_resume,
        "cancel": client.print_cancel,
        "emergency_stop": client.emergency_stop,
        "firmware_restart": client.firmware_restart,
        "restart": client.restart,
    }
    if action in simple:
        await simple[action]()
    elif action == "start":
        await client.print_start(str(params["filename"]))
    elif action == "home":
        axes = str(params.get("axes") or "").upper()
        await client.gcode_script("G28" + "".join(f" {a}" for a in axes if a in "XYZ"))
    elif action == "set_temperature":
        await client.gcode_script(temperature_gcode(params))
    elif action == "gcode":
        return await client.gcode_with_output(str(params["script"]))
    else:
        raise InvalidInput(f"Unknown action '{action}'.")
    return []


_JOB: Final = ("print_stats", "virtual_sdcard", "display_status", "idle_timeout")
_CHANGES: Final[dict[str, tuple[str, ...]]] = {
    "start": _JOB,
    "pause": _JOB,
    "resume": _JOB,
    "cancel": _JOB,
    "emergency_stop": ("webhooks",),
    "home": ("toolhead",),
    "set_temperature": ("extruder", "heater_bed"),
    "gcode": tuple(FLEET_OBJECTS),  # a script may change anything
}  # restarts: Klippy goes away, and the session follows it back


def changed_objects(action: str) -> dict[str, list[str] | None]:
    """The watched printer objects ``action`` changes, with the fields the fleet watches:
    what to read again once it is done."""
    return {name: FLEET_OBJECTS[name] for name in _CHANGES.get(action, ())}


def temperature_gcode(params: Mapping[str, Any]) -> str:
    """``{"extruder": 200, "bed": 60}`` -> ``M104 S200`` / ``M140 S60`` (no waiting)."""
    lines = []
    if params.get("extruder") is not None:
        lines.append(f"M104 S{float(params['extruder']):g}")
    if params.get("bed") is not None:
        lines.append(f"M140 S{float(params['bed']):g}")
    if not lines:
        raise InvalidInput("Give 'extruder' and/or 'bed' temperatures in °C.")
    return "\n".join(lines)


_DONE: Final = {
    "start": "Print started: {filename}.",
    "pause": "Print paused.",
    "resume": "Print resumed.",
    "cancel": "Print cancelled.",
    "emergency_stop": "Emergency stop sent: Klippy is shut down. Use firmware restart to recover.",
    "firmware_restart": "Firmware restart sent.",
    "restart": "Klippy restart sent.",
    "home": "Homed.",
    "set_temperature": "Temperatures set.",
    "gcode": "G-code done.",
}


# Klipper's errors in its console: "!! ..." lines, and unknown commands, which Klipper 0.12
# reports as plain information ('// Unknown command:"FOO"') although nothing ran.
_KLIPPER_ERROR: Final = re.compile(
    r"^(?:!!\s*(?P<error>.*)|//\s*(?P<unknown>Unknown command:.*))$", re.S
)


def klipper_errors(lines: Sequence[str]) -> list[str]:
    """The lines of a G-code's response that say it failed, in Klipper's words."""
    found = (_KLIPPER_ERROR.match(line.strip()) for line in lines)
    return [m["error"] or m["unknown"] for m in found if m]


def done_message(action: str, params: Mapping[str, Any], response: Sequence[str] = ()) -> str:
    """What to tell the user after ``action`` succeeded; for G-code that Klipper answered
    with an error line, that error (Moonraker reports success for those)."""
    errors = klipper_errors(response)
    if errors:
        return (
            f"Klipper answered with an error: {' '.join(errors)} "
            "Check the command and its parameters (HELP lists the commands)."
        )
    return _DONE.get(action, "Done.").format(filename=params.get("filename", ""))
