"""Request and response models of the job queue's API (:mod:`kybercore.api.jobs`).

Responses are read straight from the queue's dataclasses (:mod:`kybercore.jobs.models`,
``from_attributes``); requests carry the limits the queue enforces, so /openapi.json
tells clients and fuzzers the truth.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Final, Literal

from pydantic import (
    AfterValidator,
    AwareDatetime,
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
)

from kybercore.api.models import SafePath
from kybercore.jobs.models import Requirements
from kybercore.registry.models import SLUG_PATTERN, Tag

MAX_COPIES: Final = 10_000
MAX_PRIORITY: Final = 1_000
MAX_ATTEMPTS: Final = 100
MAX_TEXT: Final = 500
MAX_ID: Final = 2**31 - 1
"""Largest job id a request may name (ids are database integers)."""

PrinterId = Annotated[str, StringConstraints(pattern=SLUG_PATTERN)]
Text = Annotated[str, StringConstraints(strip_whitespace=True, max_length=MAX_TEXT)]
Material = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=32)]
ModelName = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=100)]

_DOC: Final = {
    "quantity": f"Good copies wanted, 1-{MAX_COPIES}.",
    "priority": f"Higher runs first ({-MAX_PRIORITY} to {MAX_PRIORITY}); then queue order.",
    "material": "Filament the printer must have loaded (compared case-insensitively), e.g. PLA.",
    "nozzle": "Nozzle diameter the printer must have, in mm.",
    "model": "Printer model the job needs, as in printers.json.",
    "tags": "Tags the printer must all carry (a group is a tag).",
    "printer": "Pin the job to this printer id: it runs nowhere else.",
    "not_before": "Do not start any copy before this time (ISO 8601 with a time zone).",
    "allow_mismatch": "Dispatch even where the file's metadata disagrees with a printer "
    "(nozzle, material, size warnings); logged.",
    "max_attempts": f"Failed attempts (any copy) before the job is blocked, 1-{MAX_ATTEMPTS}.",
}


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


class JobOptions(_In):
    """What a new job asks for besides its file."""

    quantity: int = Field(default=1, ge=1, le=MAX_COPIES, description=_DOC["quantity"])
    priority: int = Field(
        default=0, ge=-MAX_PRIORITY, le=MAX_PRIORITY, description=_DOC["priority"]
    )
    material: Material | None = Field(default=None, description=_DOC["material"])
    nozzle: float | None = Field(default=None, gt=0, le=5, description=_DOC["nozzle"])
    model: ModelName | None = Field(default=None, description=_DOC["model"])
    tags: list[Tag] = Field(default_factory=list, max_length=32, description=_DOC["tags"])
    not_before: AwareDatetime | None = Field(default=None, description=_DOC["not_before"])
    allow_mismatch: bool = Field(default=False, description=_DOC["allow_mismatch"])
    max_attempts: int = Field(default=3, ge=1, le=MAX_ATTEMPTS, description=_DOC["max_attempts"])

    def requirements(self, printer: str | None) -> Requirements:
        """The printer requirements these options state (``printer``: pinned, or None)."""
        return Requirements(
            material=self.material,
            nozzle=self.nozzle,
            model=self.model,
            tags=tuple(dict.fromkeys(self.tags)),
            printer=printer,
        )

    def job_fields(self, printer: str | None) -> dict[str, Any]:
        """Keyword arguments of QueueService.add_job / add_job_from_printer."""
        return {
            "quantity": self.quantity,
            "priority": self.priority,
            "not_before": self.not_before,
            "requirements": self.requirements(printer),
            "allow_mismatch": self.allow_mismatch,
            "max_attempts": self.max_attempts,
        }


class JobUpload(JobOptions):
    """The form fields of a job created by uploading its file (multipart/form-data)."""

    printer: PrinterId | None = Field(default=None, description=_DOC["printer"])


class JobFromPrinter(JobOptions):
    """A job made of a file already on a printer: KyberCore copies it from there."""

    printer: PrinterId = Field(description="The printer that holds the file.")
    path: SafePath = Field(description="The file, relative to that printer's gcodes/ folder.")
    pin: bool = Field(
        default=False, description="Print it only on that printer (else on any that fits)."
    )


def _form_field(schema: dict[str, Any]) -> dict[str, Any]:
    """A field's schema in a form, which has no null: an optional field is left out."""
    kept = [branch for branch in schema.get("anyOf", []) if branch.get("type") != "null"]
    if not kept:
        return schema
    rest = {k: v for k, v in schema.items() if k != "anyOf" and (k, v) != ("default", None)}
    return {**kept[0], **rest}


UPLOAD_FORM_SCHEMA: Final[dict[str, Any]] = {
    "title": "JobUploadForm",
    "type": "object",
    "required": ["file"],
    "properties": {
        "file": {"type": "string", "format": "binary", "description": "The G-code file."},
        **{
            name: _form_field(field)
            for name, field in JobUpload.model_json_schema()["properties"].items()
        },
    },
}
"""The multipart form of ``POST /api/jobs``: the file plus :class:`JobUpload`'s fields."""


class JobPatch(_In):
    """Change a job; omitted fields keep their value."""

    priority: int | None = Field(
        default=None, ge=-MAX_PRIORITY, le=MAX_PRIORITY, description=_DOC["priority"]
    )
    quantity: int | None = Field(
        default=None,
        ge=1,
        le=MAX_COPIES,
        description=_DOC["quantity"] + " Not below the copies done and in flight.",
    )
    not_before: AwareDatetime | None = Field(
        default=None, description=_DOC["not_before"] + " null clears it."
    )
    max_attempts: int | None = Field(
        default=None, ge=1, le=MAX_ATTEMPTS, description=_DOC["max_attempts"]
    )


class MoveRequest(_In):
    """Where to put a job in the queue."""

    before: int | None = Field(
        default=None,
        ge=1,
        le=MAX_ID,
        description="Put it just before this job (by id); null puts it last.",
    )


class QueueChange(_In):
    """Pause or resume dispatching."""

    paused: bool = Field(description="true: no new copy starts; prints under way go on.")


class ClearRequest(_In):
    """An operator's word on the plate of a printer awaiting a clear."""

    verdict: Literal["good", "bad"] = Field(
        description="good: the copy counts as done; bad: the copy goes back to the queue."
    )
    cause: Text = Field(default="", description="Why it is bad (spaghetti, warping…); optional.")


class HoldRequest(_In):
    """Take a printer out of the queue's hands."""

    reason: Annotated[str, StringConstraints(strip_whitespace=True, min_length=1)] = Field(
        max_length=MAX_TEXT, description="Why, shown to everyone (e.g. 'nozzle change')."
    )


# -- responses --------------------------------------------------------------------------


def _utc(value: datetime) -> datetime:
    # A database may hand back naive datetimes; the queue stores UTC.
    return value if value.tzinfo is not None else value.replace(tzinfo=UTC)


Instant = Annotated[datetime, AfterValidator(_utc)]
"""A point in time, answered in ISO 8601 with its offset (UTC)."""


class _Out(BaseModel):
    model_config = ConfigDict(from_attributes=True)


class RequirementsOut(_Out):
    """What a printer must have to run the job; null or empty means any."""

    material: str | None = Field(description="Filament the printer must have loaded.")
    nozzle: float | None = Field(description="Nozzle diameter in mm.")
    model: str | None = Field(description="Printer model, as in printers.json.")
    tags: list[str] = Field(description="Tags the printer must all carry.")
    printer: str | None = Field(description="Pinned printer id.")


class JobFileOut(_Out):
    """The job's file, stored once by KyberCore."""

    sha256: str = Field(description="The content's hash: the file is stored once under it.")
    name: str = Field(description="The name it was uploaded with.")
    size: int = Field(description="Bytes.")
    meta: dict[str, Any] = Field(
        description="Slicer metadata as Moonraker's parser reads it (estimated_time, "
        "filament_type, nozzle_diameter, object_height…)."
    )


class JobOut(_Out):
    """A job and its copies: done, in flight (printing or awaiting a clear) and left."""

    id: int = Field(description="The job's id.")
    file: JobFileOut
    quantity: int = Field(description="Good copies wanted.")
    done: int = Field(description="Copies cleared good.")
    in_flight: int = Field(description="Copies printing, or printed and awaiting a clear.")
    awaiting_clear: int = Field(
        description="Of in_flight, the copies printed whose plate awaits a clear."
    )
    left: int = Field(description="Copies no printer has yet.")
    failures: int = Field(description="Attempts that failed or did not start.")
    priority: int = Field(description="Higher runs first.")
    position: float = Field(description="Order among jobs of the same priority (lower first).")
    state: Literal["queued", "blocked", "done", "cancelled"] = Field(
        description="queued: copies to print or in flight; blocked: too many failed "
        "attempts (requeue it); done: every copy cleared good; cancelled."
    )
    reason: str = Field(description="Why it is blocked or cancelled.")
    not_before: Instant | None = Field(description="No copy starts before this time.")
    requirements: RequirementsOut
    allow_mismatch: bool = Field(description="Dispatched even where the file disagrees.")
    max_attempts: int = Field(description="Failed attempts before the job is blocked.")
    created_at: Instant
    created_by: str = Field(description="Who queued it.")


class AttemptOut(_Out):
    """One copy of a job on one printer."""

    id: int = Field(description="The attempt's id.")
    job_id: int
    # Not "copy": a pydantic model has a method of that name.
    copy_: int = Field(
        validation_alias="copy", serialization_alias="copy", description="Which copy, 1..quantity."
    )
    printer: str = Field(description="The printer it runs on.")
    upload_name: str = Field(description="The file's unique name on the printer.")
    state: Literal[
        "pending", "uploading", "starting", "printing", "paused",
        "completed", "failed", "cancelled", "failed_to_start",
    ]  # fmt: skip
    reason: str = Field(description="Why it ended as it did (failed, did not start…).")
    moonraker_job_id: str | None = Field(description="Moonraker's history job id.")
    verdict: Literal["good", "bad"] | None = Field(description="The plate's verdict, once given.")
    cause: str = Field(description="Why the plate was bad, when the operator said.")
    user: str = Field(description="Who (or what) acted on it last.")
    created_at: Instant
    started_at: Instant | None = Field(description="When it started printing.")
    ended_at: Instant | None
    print_seconds: float = Field(description="Print time as Moonraker reported it.")


class GateOut(_Out):
    """Whether a printer's plate may receive the next print."""

    printer: str = Field(description="The printer's id.")
    state: Literal["available", "awaiting_clear", "held", "maintenance"] = Field(
        description="awaiting_clear: a print ended, an operator must clear the plate."
    )
    reason: str = Field(description="Why it is held, in maintenance or awaiting a clear.")
    since: Instant = Field(description="When it entered this state.")
    attempt_id: int | None = Field(
        description="The attempt printing there, or the ended one whose plate awaits a clear."
    )
    user: str = Field(description="Who put it in this state.")


class WhyLineOut(_Out):
    """One reason a job is not running somewhere right now, in English and Spanish."""

    subject: str = Field(description="A printer id, 'power group X', or 'queue'.")
    code: str = Field(description="A stable name of the reason (needs_material, awaiting_clear…).")
    en: str
    es: str


class QueueState(BaseModel):
    """The queue at a glance."""

    paused: bool = Field(description="No new copy starts while true.")
    queued: int = Field(description="Jobs with copies left or in flight.")
    blocked: int = Field(description="Jobs stopped after too many failed attempts.")
    copies_left: int = Field(description="Copies no printer has yet, over queued jobs.")
    copies_in_flight: int = Field(description="Copies printing or awaiting a clear.")
    copies_printing: int = Field(description="Of copies_in_flight, those not printed yet.")
    awaiting_clear: list[str] = Field(description="Printers whose plate awaits a clear.")
    held: list[str] = Field(description="Printers held or in maintenance.")
