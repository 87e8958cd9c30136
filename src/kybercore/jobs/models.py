"""The job queue's vocabulary: jobs, the attempts that print their copies, printer gates.

Pure data, shared by the store (:mod:`kybercore.jobs.store`), the planner
(:mod:`kybercore.jobs.rules`), the dispatcher and the API. A job asks for ``quantity`` good
copies of one file; each copy runs as an :class:`Attempt` on one printer. A printer's
:class:`Gate` says whether its plate may receive a print: every print that ends, well or
badly, leaves it ``awaiting_clear`` until an operator clears it with a verdict.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Final, Literal

JobState = Literal["queued", "blocked", "done", "cancelled"]
"""``queued``: copies left to run or in flight. ``blocked``: it failed ``max_attempts`` times
(``reason`` says why); an operator may requeue it. ``done``: ``quantity`` good copies."""

AttemptState = Literal[
    "pending", "uploading", "starting", "printing", "paused",
    "completed", "failed", "cancelled", "failed_to_start",
]  # fmt: skip
LIVE: Final[frozenset[str]] = frozenset({"pending", "uploading", "starting", "printing", "paused"})
"""An attempt in one of these states holds its printer and its copy."""
ENDED: Final[frozenset[str]] = frozenset({"completed", "failed", "cancelled", "failed_to_start"})

GateState = Literal["available", "awaiting_clear", "held", "maintenance"]
PlateVerdict = Literal["good", "bad"]


@dataclass(frozen=True)
class Requirements:
    """What a printer must have to run a job; ``None``/empty means "any"."""

    material: str | None = None
    """Loaded filament type, compared case-insensitively (``PLA``)."""
    nozzle: float | None = None
    """Nozzle diameter in mm."""
    model: str | None = None
    """Printer model as in printers.json."""
    tags: tuple[str, ...] = ()
    """Every tag must be on the printer (a group is a tag)."""
    printer: str | None = None
    """Pinned: only this printer id."""


@dataclass(frozen=True)
class JobFile:
    """A G-code file stored once by KyberCore, named by its content's sha256."""

    sha256: str
    name: str
    """The name it was uploaded with (``benchy.gcode``)."""
    size: int
    meta: Mapping[str, Any] = field(default_factory=dict)
    """Slicer metadata as Moonraker's own parser reads it (``estimated_time``,
    ``filament_type``, ``nozzle_diameter``, ``object_height``, ``first_layer_extr_temp``…)."""


@dataclass(frozen=True)
class NewJob:
    """What a user asks for when queueing a job."""

    file: JobFile
    quantity: int = 1
    priority: int = 0
    """Higher runs first."""
    not_before: datetime | None = None
    requirements: Requirements = field(default_factory=Requirements)
    allow_mismatch: bool = False
    """Dispatch even when the file's metadata disagrees with a printer (logged)."""
    max_attempts: int = 3
    """Failed attempts (any copy) before the job is blocked."""


@dataclass(frozen=True)
class Job:
    """A queued job and its counters, as stored."""

    id: int
    file: JobFile
    quantity: int
    priority: int
    position: float
    """Order among jobs of the same priority (lower first); reordering changes it."""
    not_before: datetime | None
    requirements: Requirements
    allow_mismatch: bool
    max_attempts: int
    state: JobState
    reason: str
    done: int
    """Copies cleared ``good``."""
    in_flight: int
    """Copies with a live attempt, or completed and awaiting a verdict."""
    awaiting_clear: int
    """Of ``in_flight``, the copies completed and awaiting their plate's verdict."""
    failures: int
    """Attempts that ended ``failed`` or ``failed_to_start``."""
    created_at: datetime
    created_by: str

    @property
    def left(self) -> int:
        """Copies nobody is printing yet."""
        return self.quantity - self.done - self.in_flight


@dataclass(frozen=True)
class Attempt:
    """One copy of a job on one printer."""

    id: int
    job_id: int
    copy: int
    """Which copy, 1..quantity; a copy sent back by a ``bad`` verdict runs again."""
    printer: str
    upload_name: str
    """Unique per attempt: how Moonraker's history names the print."""
    state: AttemptState
    reason: str
    moonraker_job_id: str | None
    verdict: PlateVerdict | None
    cause: str
    user: str
    created_at: datetime
    started_at: datetime | None
    ended_at: datetime | None
    print_seconds: float
    """Print duration as Moonraker reported it (wear-levelling counts it)."""

    @property
    def live(self) -> bool:
        """Whether it still holds its printer and copy."""
        return self.state in LIVE


@dataclass(frozen=True)
class Gate:
    """Whether a printer's plate may receive the next print."""

    printer: str
    state: GateState
    reason: str
    since: datetime
    attempt_id: int | None
    """The live attempt on the printer, or the ended one whose plate awaits a clear."""
    user: str
