"""Whether one printer may take one job now: the facts, the requirements, the verdict. Pure.

A printer may take a job when it is free (online, Klippy ready, idle: no print running and
no attempt on it, gate ``available``), meets the job's requirements (loaded material,
nozzle, model, tags, pinned printer) and :func:`kybercore.core.validation.validate` finds
nothing that blocks a start of the file there. A warning (another filament or printer model
than the file was sliced for, a file without metadata) stops it too, unless the job allows a
mismatch. Facts that are not known (no loaded material recorded, a nozzle not read yet) are
never guessed: such a printer does not take a job that needs them.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Final

from kybercore.core.validation import PrinterFacts, Verdict, validate
from kybercore.jobs.models import Gate, JobFile, Requirements
from kybercore.jobs.reasons import WhyLine, line

IDLE_STATES: Final = frozenset({"standby", "complete", "cancelled", "error"})
"""``print_stats.state`` values in which a printer can start a print."""
NOZZLE_TOLERANCE: Final = 0.01
"""mm: nozzles closer than this are the same size (as in validation)."""


@dataclass(frozen=True)
class PrinterSnapshot:
    """What the planner knows about one printer at the start of a round."""

    id: str
    facts: PrinterFacts
    """Live state and capabilities, as validation reads them (``model`` and the loaded
    ``material`` included)."""
    gate: Gate
    tags: tuple[str, ...] = ()
    power_group: str = ""
    """See :func:`kybercore.jobs.heating.power_group`."""
    heating: bool = False
    """See :func:`kybercore.jobs.heating.is_heating`."""
    usage_seconds: float = 0.0
    """Print time in the usage window (wear-levelling)."""
    last_used: datetime | None = None
    """When its last attempt started; None if never."""

    @property
    def idle(self) -> bool:
        """No print running or paused on it, and no attempt of the queue holding it."""
        return self.facts.print_state in IDLE_STATES and self.gate.attempt_id is None

    @property
    def free(self) -> bool:
        """Whether it can take a job now, whatever the job: online, Klippy ready, idle and
        its gate available."""
        facts = self.facts
        return (
            facts.connection == "online"
            and facts.klippy_state == "ready"
            and self.gate.state == "available"
            and self.idle
        )


FactsKey = tuple[Any, ...]


def facts_key(facts: PrinterFacts) -> FactsKey:
    """What a start's verdict depends on, for a free printer (its exact idle state aside)."""
    return (
        facts.model, facts.build_volume, facts.axis_minimum, facts.nozzle_diameter,
        facts.material, facts.max_extruder_temp, facts.max_bed_temp, facts.limits,
        facts.filament_left_g,
    )  # fmt: skip


class Memo:
    """Verdicts of starting a file on a printer, kept between rounds.

    Keyed by the file (sha256 and name) and :func:`facts_key`; the metadata is compared on
    a hit, so a file stored again with other metadata is judged again. Only ask it about
    free printers (see :attr:`PrinterSnapshot.free`).
    """

    def __init__(self, limit: int = 200_000) -> None:
        self._limit = limit
        self._verdicts: dict[tuple[str, str, FactsKey], _Judged] = {}

    def verdict(self, file: JobFile, facts: PrinterFacts, key: FactsKey | None = None) -> Verdict:
        """:func:`validate` of starting ``file`` on the printer with ``facts``."""
        return self._judged(file, facts, key).verdict

    def warnings(
        self, file: JobFile, facts: PrinterFacts, key: FactsKey, allow_mismatch: bool
    ) -> tuple[str, ...] | None:
        """``code: message`` of each warning of a start that may be dispatched, or None
        when it may not: something blocks it, or it warns and the job allows no mismatch."""
        judged = self._judged(file, facts, key)
        if judged.blocked or (judged.warnings and not allow_mismatch):
            return None
        return judged.warnings

    def _judged(self, file: JobFile, facts: PrinterFacts, key: FactsKey | None) -> _Judged:
        memo_key = (file.sha256, file.name, facts_key(facts) if key is None else key)
        hit = self._verdicts.get(memo_key)
        if hit is not None and (hit.meta is file.meta or hit.meta == file.meta):
            return hit
        # An empty metadata dict means the parser found nothing: a file without metadata.
        verdict = validate(
            "start", facts, params={"filename": file.name}, file_meta=file.meta or None
        )
        if len(self._verdicts) >= self._limit:
            self._verdicts.clear()  # crude, but a round never needs more than it refills
        warnings = tuple(f"{r.code}: {r.en}" for r in verdict.warnings)
        judged = _Judged(file.meta, verdict, verdict.blocked, warnings)
        self._verdicts[memo_key] = judged
        return judged


@dataclass(frozen=True)
class _Judged:
    meta: Mapping[str, Any]
    verdict: Verdict
    blocked: bool
    warnings: tuple[str, ...]


def normal_model(name: str) -> str:
    """A model name compared loosely: "Voron 2.4" is "voron2.4" is "VORON-2.4"."""
    return re.sub(r"[^a-z0-9.]", "", name.casefold())


def normal_tags(tags: Collection[str]) -> frozenset[str]:
    """Tags compared case-insensitively."""
    return frozenset(t.strip().casefold() for t in tags)


Problem = tuple[str, dict[str, str | float]]
UNKNOWN_FACTS: Final = frozenset({"material_unknown", "nozzle_unknown"})
"""Codes of :func:`unmet` that say a fact is missing rather than wrong."""


def problem(req: Requirements, facts: PrinterFacts, tags: frozenset[str]) -> Problem | None:
    """The first requirement ``facts`` and ``tags`` do not meet, as a code of
    :mod:`kybercore.jobs.reasons` and its values, or None. A clear mismatch comes before a
    fact that is not known."""
    material = (facts.material or "").strip()
    wanted = (req.material or "").strip()
    if wanted and material and material.casefold() != wanted.casefold():
        return "needs_material", {"loaded": material, "material": wanted}
    nozzle = facts.nozzle_diameter
    if (
        req.nozzle is not None
        and nozzle is not None
        and abs(nozzle - req.nozzle) > NOZZLE_TOLERANCE
    ):
        return "needs_nozzle", {"ours": nozzle, "nozzle": req.nozzle}
    if req.model and normal_model(facts.model) != normal_model(req.model):
        return "needs_model", {"ours": facts.model, "model": req.model}
    missing = [t for t in req.tags if t.strip().casefold() not in tags]
    if missing:
        return "needs_tags", {"tags": ", ".join(missing)}
    if wanted and not material:
        return "material_unknown", {"material": wanted}
    if req.nozzle is not None and nozzle is None:
        return "nozzle_unknown", {"nozzle": req.nozzle}
    return None


def unmet(
    subject: str, req: Requirements, facts: PrinterFacts, tags: frozenset[str]
) -> WhyLine | None:
    """:func:`problem` as a line about ``subject``."""
    found = problem(req, facts, tags)
    return None if found is None else line(subject, found[0], **found[1])


def clock(when: datetime, now: datetime) -> str:
    """``when`` as an operator reads it: ``14:02`` today, else ``2025-05-01 14:02``, in
    ``now``'s time zone."""
    if when.tzinfo is not None and now.tzinfo is not None:
        when = when.astimezone(now.tzinfo)
    return when.strftime("%H:%M" if when.date() == now.date() else "%Y-%m-%d %H:%M")
