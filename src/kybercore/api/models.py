"""Request and response models of the REST API (they are what /openapi.json documents).

Live printer views stay plain dicts inside the service for speed; these models describe
them for clients and validate what clients send. Action outcomes and verdicts become
response bodies here too (:func:`action_result`, :func:`check_result`), so every router
answers them alike.
"""

from __future__ import annotations

from typing import Annotated, Any, Final, Literal

from fastapi import Query
from pydantic import BaseModel, ConfigDict, Field, StringConstraints

from kybercore.api.errors import error_status
from kybercore.core.paths import MAX_PATH, SAFE_PATH_PATTERN
from kybercore.core.validation import Verdict
from kybercore.fleet.actions import ActionOutcome, reason_dict
from kybercore.registry.models import Capabilities, Url

ActionName = Literal[
    "start",
    "pause",
    "resume",
    "cancel",
    "emergency_stop",
    "firmware_restart",
    "restart",
    "home",
    "set_temperature",
]

MAX_SCRIPT_CHARS = 64 * 1024


SafePath = Annotated[
    str,
    StringConstraints(max_length=MAX_PATH),
    Field(json_schema_extra={"pattern": SAFE_PATH_PATTERN}),
]
"""A file path relative to gcodes/, documented as :func:`~kybercore.core.paths.safe_path`
checks it (the service still calls it, for its message)."""


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ActionRequest(_In):
    """Parameters of an action; only those the action uses are read."""

    filename: SafePath | None = Field(
        default=None, description="start: the G-code file to print, relative to gcodes/."
    )
    extruder: float | None = Field(
        default=None, ge=0, le=1000, description="set_temperature: hotend target in °C."
    )
    bed: float | None = Field(
        default=None, ge=0, le=1000, description="set_temperature: bed target in °C."
    )
    axes: str | None = Field(
        default=None, pattern=r"^[xyzXYZ]{0,3}$", description="home: axes to home; all if empty."
    )
    force: bool = Field(
        default=False, description="Allow restarts while printing (the only blocks force lifts)."
    )
    confirm: bool = Field(default=False, description="Go ahead despite warnings.")

    def params(self) -> dict[str, Any]:
        """The action's parameters without the force/confirm flags."""
        return self.model_dump(exclude={"force", "confirm"}, exclude_none=True)


FilePath = Annotated[
    str,
    Query(
        json_schema_extra={"pattern": SAFE_PATH_PATTERN, "maxLength": MAX_PATH},
        description="A path relative to the printer's gcodes/ folder, without '..'.",
    ),
]
"""A file path in a query string, documented as :func:`~kybercore.core.paths.safe_path`
checks it; the route calls it, so a bad path is explained in its words."""


class FleetActionRequest(ActionRequest):
    """One action on several printers."""

    printer_ids: list[str] = Field(
        min_length=1, max_length=10_000, description="Printers to act on, by id."
    )
    stagger_seconds: float = Field(
        default=0.0,
        ge=0,
        le=600,
        description="For start: seconds between one printer's start and the next, in the "
        "order given (a room of printers heating at once can trip a breaker). The server "
        "keeps the pace; closing the page does not stop it.",
    )

    def params(self) -> dict[str, Any]:
        """The action's parameters: which printers, and their pace, are not among them."""
        return self.model_dump(
            exclude={"force", "confirm", "printer_ids", "stagger_seconds"}, exclude_none=True
        )


class GcodeRequest(_In):
    """A G-code script to run on one printer."""

    script: str = Field(min_length=1, max_length=MAX_SCRIPT_CHARS, description="G-code lines.")
    force: bool = Field(default=False, description="Allow restarts or SAVE_CONFIG mid-print.")
    confirm: bool = Field(default=False, description="Go ahead despite warnings.")


class ReasonOut(BaseModel):
    """One validation finding, in English and Spanish."""

    code: str
    level: Literal["ok", "warn", "block"]
    category: str = Field(
        default="", description="What it is about (a printer check's kind); absent for the queue's."
    )
    en: str
    es: str


class ActionResult(BaseModel):
    """The real outcome of an action on one printer."""

    printer_id: str
    action: str
    ok: bool
    status: int = Field(description="HTTP status this outcome has on its own.")
    code: str = Field(description="'ok' or a stable error code.")
    message: str
    reasons: list[ReasonOut] = Field(default_factory=list)


def action_result(outcome: ActionOutcome) -> dict[str, Any]:
    """An :class:`ActionResult` body for ``outcome``."""
    if outcome.error is not None:
        status = error_status(outcome.error)[0]
    else:
        status = 201 if outcome.action == "upload" else 200
    return {
        "printer_id": outcome.printer_id,
        "action": outcome.action,
        "ok": outcome.ok,
        "status": status,
        "code": outcome.code,
        "message": outcome.message,
        "reasons": outcome.reasons,
    }


class GcodeResult(ActionResult):
    """A G-code's outcome with what Klipper answered. Klipper reports some failures
    (``!!`` lines, unknown commands) as responses while Moonraker reports success: those
    keep ``ok`` true, and ``message`` quotes them."""

    response: list[str] = Field(
        default_factory=list,
        description="Klipper's response lines while the G-code ran, in order "
        "(e.g. M115: '// FIRMWARE_NAME:Klipper ...'; errors start with '!!').",
    )


def gcode_result(outcome: ActionOutcome) -> dict[str, Any]:
    """A :class:`GcodeResult` body for ``outcome``."""
    return {**action_result(outcome), "response": outcome.response}


class ConsoleEntry(BaseModel):
    """One line of a printer's console, as Moonraker's G-code store keeps it."""

    message: str
    time: float = Field(description="Unix time, by the printer's clock.")
    type: str = Field(description="'command' (sent by any client) or 'response' (Klipper's).")


class UploadResult(ActionResult):
    """An upload (always ``ok`` and 201 once the file is stored) and, when ``start`` was
    asked, the start that followed: done, or refused with its reasons, which are copied
    to the upload's own ``reasons``. A refused start never means the file is missing:
    start it later with ``POST .../actions/start``."""

    uploaded: bool = Field(description="The file is stored on the printer (always true).")
    started: bool | None = Field(
        description="Whether the print started; null when start was not asked."
    )
    start: ActionResult | None = Field(
        description="The start's own result (status, code, message, reasons); null when "
        "start was not asked."
    )


def upload_result(outcome: ActionOutcome) -> dict[str, Any]:
    """An :class:`UploadResult` body for a done upload ``outcome``."""
    start = outcome.start
    return {
        **action_result(outcome),
        "uploaded": True,
        "started": None if start is None else start.ok,
        "start": None if start is None else action_result(start),
    }


class FleetActionResult(BaseModel):
    """One outcome per printer, in the order asked."""

    results: list[ActionResult]


class CheckResult(BaseModel):
    """What validation says about an action, without doing it (dry run)."""

    printer_id: str
    action: str
    level: Literal["ok", "warn", "block"]
    reasons: list[ReasonOut]


def check_result(printer_id: str, action: str, verdict: Verdict) -> dict[str, Any]:
    """A :class:`CheckResult` body for ``verdict``."""
    return {
        "printer_id": printer_id,
        "action": action,
        "level": verdict.level,
        "reasons": [reason_dict(r) for r in verdict.reasons],
    }


class FleetCheckResult(BaseModel):
    """Dry-run verdicts, one per printer."""

    results: list[CheckResult]


class FieldError(BaseModel):
    """What is wrong with one field of the request (422 answers)."""

    field: str = Field(description="Dotted path of the field, e.g. 'capabilities.material'.")
    en: str
    es: str


class ErrorBody(BaseModel):
    """Every error answer: ``{"error": {...}}``."""

    code: str
    message: str
    reasons: list[ReasonOut] = Field(default_factory=list)
    fields: list[FieldError] = Field(
        default_factory=list, description="Per-field problems of an invalid request."
    )


class ErrorResponse(BaseModel):
    """The envelope of an error."""

    error: ErrorBody


ERROR_RESPONSES: Final[dict[int | str, dict[str, Any]]] = {
    status: {"model": ErrorResponse} for status in (404, 409, 422, 502, 503, 504)
}
"""The error answers a route documents (``responses=``) besides its own."""


class Heater(BaseModel):
    """A heater's reading; null while unknown."""

    temperature: float | None
    target: float | None
    power: float | None


class Job(BaseModel):
    """The print job the printer is on (or last ran)."""

    state: str = Field(description="standby, printing, paused, complete, cancelled, error or ''.")
    filename: str
    progress: float = Field(
        description="0 to 1: the file position within the G-code; never goes back during a print."
    )
    eta_seconds: int | None = Field(
        description="Seconds left, while printing or paused; null until extrusion starts."
    )
    eta_at: int | None = Field(
        description="When the print will be done (Unix seconds), with ``eta_seconds``."
    )
    estimated_time: float | None = Field(description="The slicer's estimate for the whole file.")
    print_duration: int
    total_duration: int
    message: str
    layer: int | None
    total_layers: int | None
    thumbnail: str | None = Field(description="Path of the largest thumbnail, under gcodes/.")


class Toolhead(BaseModel):
    """Where the toolhead is."""

    position: list[float] | None
    homed_axes: str
    axis_minimum: list[float] | None = Field(
        default=None, description="Klipper's lowest X, Y and Z position (position_min)."
    )


class SpoolOut(BaseModel):
    """The printer's active Spoolman spool (through Moonraker's ``[spoolman]``)."""

    id: int
    name: str = Field(description="Vendor and filament name.")
    material: str
    color_hex: str = Field(description='"RRGGBB", or "" when unknown.')
    remaining_g: float | None = Field(description="Grams left, as Spoolman counts them.")
    low: bool = Field(description="Fewer grams left than the low-filament threshold.")


class PrinterView(BaseModel):
    """A printer's configuration fused with its live state. Never holds the API key."""

    id: str
    name: str
    model: str
    location: str
    tags: list[str]
    notes: str
    moonraker_url: Url
    api_key_set: bool
    enabled: bool
    capabilities: Capabilities = Field(
        description="Effective limits: printers.json's values, else Klippy's."
    )
    limits: Literal["known", "loading", "unknown"] = Field(
        description="Whether the limits are known (printers.json gives them all, or Klippy's "
        "configfile was read), loading (being read after a connect) or unknown (the read "
        "failed and is retried). Until known, start, set_temperature and G-code are refused."
    )
    connection: str = Field(description="connecting, online, offline, auth_failed or disabled.")
    connection_error: str
    klippy_state: str = Field(description="ready, startup, shutdown, error or disconnected.")
    klippy_message: str
    job: Job
    extruder: Heater
    bed: Heater
    toolhead: Toolhead
    fan_speed: float | None
    speed_factor: float | None = Field(description="M220 as a fraction (1.0 = 100 %).")
    extrude_factor: float | None = Field(description="M221 (flow) as a fraction.")
    z_offset: float | None = Field(description="The Z babystep, mm (SET_GCODE_OFFSET).")
    can_extrude: bool = Field(description="The hotend is above min_extrude_temp.")
    runout: bool = Field(description="An enabled filament sensor reports no filament.")
    spool: SpoolOut | None = Field(description="null without [spoolman] or an active spool.")
    spoolman: Literal["unknown", "absent", "none", "active", "unreachable"] = Field(
        description="Spoolman as the printer's Moonraker sees it: not read yet, no "
        "[spoolman] configured, no spool set active, a spool active, or a spool set that "
        "Spoolman did not answer with."
    )
    actions: dict[str, bool] = Field(description="Which actions are valid in the current state.")
    updated_at: float = Field(description="Unix time of the last message from Moonraker.")


class Health(BaseModel):
    """Whether KyberCore is up, and a one-line picture of the fleet."""

    status: Literal["ok"]
    version: str
    printers: int
    online: int
    browsers: int
    config_error: str | None = Field(description="Why the last printers.json edit was refused.")
    broker: Literal["connected", "disconnected"] | None = Field(
        None,
        description="A front on NATS: whether it is connected to the broker now (while "
        "disconnected its printers are stale and its actions refused). None on serve.",
    )


class Ready(BaseModel):
    """This process can serve the fleet now (a load balancer's check)."""

    ready: Literal[True]


class FileItem(BaseModel):
    """A G-code file on a printer."""

    model_config = ConfigDict(extra="allow")

    path: str
    modified: float
    size: int
