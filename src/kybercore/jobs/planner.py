"""One dispatch round: which queued job goes to which printer now. Pure: no I/O, no clock.

Which printer may take which job is :mod:`kybercore.jobs.eligibility`.

Jobs go in queue order (priority, then position, then id), each up to the copies it has
left. Among the printers that may take a job the least worn goes first: the least print
time in the usage window, then the least recently used, then the id. For a job that failed
before, printers that ran it fewer times go first. A power group may have at most K
printers heating at once, starts in progress included.

Speed: a round over 5,000 printers and 10,000 jobs stays within milliseconds because
printers that are interchangeable for every job (same facts and tags) are judged once as a
kind, validation verdicts are kept in a :class:`Memo` between rounds, a kind is only
validated when its best printer would be picked, and the round stops once no printer can
take anything.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime

from kybercore.core.validation import PrinterFacts
from kybercore.jobs.eligibility import (
    FactsKey,
    Memo,
    PrinterSnapshot,
    accepts,
    clock,
    facts_key,
    normal_tags,
    problem,
    warning_texts,
)
from kybercore.jobs.models import Job, Requirements
from kybercore.jobs.reasons import QUEUE, WhyLine, line


@dataclass(frozen=True)
class Assignment:
    """A copy of ``job_id`` to start on ``printer``."""

    job_id: int
    printer: str
    warnings: tuple[str, ...] = ()
    """``code: message`` of each mismatch the job allowed (to be logged)."""


@dataclass(frozen=True)
class Plan:
    """The outcome of a round."""

    assignments: list[Assignment]
    waiting: dict[int, list[WhyLine]] = field(default_factory=dict)
    """Jobs held as a whole this round (queue paused, not before a time), with why.
    :func:`kybercore.jobs.why.why` explains a job printer by printer."""


def job_order(job: Job) -> tuple[int, float, int]:
    """Queue order: priority (higher first), then position, then id."""
    return (-job.priority, job.position, job.id)


def plan(
    jobs: Sequence[Job],
    printers: Sequence[PrinterSnapshot],
    *,
    heating_budget: int | None,
    starting: Collection[str] = (),
    now: datetime,
    paused: bool = False,
    attempts_per_printer: Mapping[int, Mapping[str, int]] | None = None,
    memo: Memo | None = None,
) -> Plan:
    """Assign queued jobs to free printers for this round.

    ``heating_budget``: at most this many printers of one power group heating at once
    (None: no limit). ``starting``: ids of printers whose start is in progress (reserved,
    uploading, starting, or printing but not yet seen heating); they count against the
    budget like heating ones. ``attempts_per_printer``: job id -> printer -> attempts of
    that job there; used for jobs with failures. ``memo``: keep one between rounds to
    reuse verdicts.
    """
    queued = sorted((j for j in jobs if j.state == "queued" and j.left > 0), key=job_order)
    if paused:
        held = [line(QUEUE, "queue_paused")]
        return Plan([], {j.id: held for j in queued})
    waiting: dict[int, list[WhyLine]] = {}
    ready: list[Job] = []
    for job in queued:
        if job.not_before is not None and job.not_before > now:
            waiting[job.id] = [line(QUEUE, "not_before", time=clock(job.not_before, now))]
        else:
            ready.append(job)
    state = Round(printers, heating_budget, starting, memo or Memo())
    for job in ready:
        if state.usable <= 0:
            break
        attempts = (attempts_per_printer or {}).get(job.id) if job.failures else None
        state.assign(job, attempts)
    return Plan(state.assignments, waiting)


@dataclass(eq=False)
class Kind:
    """Free printers that every job judges alike: same facts and tags. Its queue holds
    ``(rank, printer)`` best first; printers taken or shut out by power leave it lazily."""

    facts: PrinterFacts
    key: FactsKey
    tags: frozenset[str]
    queue: deque[tuple[int, PrinterSnapshot]] = field(default_factory=deque)


class Round:
    """The bookkeeping of one round: free printers by kind, power per group, what is taken."""

    def __init__(
        self,
        printers: Sequence[PrinterSnapshot],
        budget: int | None,
        starting: Collection[str],
        memo: Memo,
    ) -> None:
        self.budget = budget
        self.memo = memo
        self.assignments: list[Assignment] = []
        self.taken: dict[str, int] = {}
        """Printer id -> the job it got this round."""
        self.power: dict[str, int] = {}
        """Power group -> printers heating or starting, this round's starts included."""
        starting = set(starting)
        self.drawing: set[str] = set()
        """Printers already counted in their group (heating or starting)."""
        for p in printers:
            if p.heating or p.id in starting:
                self.drawing.add(p.id)
                self.power[p.power_group] = self.power.get(p.power_group, 0) + 1
        free = sorted((p for p in printers if p.free), key=_wear)
        self.kinds: list[Kind] = []
        self.free_by_id: dict[str, tuple[PrinterSnapshot, Kind]] = {}
        self.idle_in: dict[str, int] = {}
        """Power group -> free printers not taken that would start heating."""
        by_key: dict[tuple[FactsKey, frozenset[str]], Kind] = {}
        tag_sets: dict[tuple[str, ...], frozenset[str]] = {}
        for rank, p in enumerate(free):
            tags = tag_sets.get(p.tags)
            if tags is None:
                tags = tag_sets[p.tags] = normal_tags(p.tags)
            key = facts_key(p.facts)
            kind = by_key.get((key, tags))
            if kind is None:
                kind = by_key[(key, tags)] = Kind(p.facts, key, tags)
                self.kinds.append(kind)
            kind.queue.append((rank, p))
            self.free_by_id[p.id] = (p, kind)
            if p.id not in self.drawing:
                self.idle_in[p.power_group] = self.idle_in.get(p.power_group, 0) + 1
        self.usable = len(free) - sum(n for g, n in self.idle_in.items() if self.full(g))
        """Free printers left that could still take a job this round."""
        self._candidates: dict[Requirements, list[Kind]] = {}
        self.by_material: dict[str, list[Kind]] = {}
        for kind in self.kinds:
            material = (kind.facts.material or "").strip().casefold()
            self.by_material.setdefault(material, []).append(kind)

    def full(self, group: str) -> bool:
        """Whether no other printer of ``group`` may start heating."""
        return self.budget is not None and self.power.get(group, 0) >= self.budget

    def usable_printer(self, p: PrinterSnapshot) -> bool:
        """Whether ``p`` (free) can still be given a job this round."""
        return p.id not in self.taken and (p.id in self.drawing or not self.full(p.power_group))

    def head(self, kind: Kind) -> tuple[int, PrinterSnapshot] | None:
        """The best printer of ``kind`` still usable, dropping the ones that no longer are."""
        queue = kind.queue
        while queue:
            if self.usable_printer(queue[0][1]):
                return queue[0]
            queue.popleft()  # taken, or its group is full: it will not come back this round
        return None

    def candidates(self, req: Requirements) -> list[Kind]:
        """Kinds whose printers meet ``req`` (the pinned printer aside); a new
        list each time (:meth:`_best` drops refused kinds from it)."""
        found = self._candidates.get(req)
        if found is None:
            kinds = (
                self.by_material.get(req.material.strip().casefold(), [])
                if req.material
                else self.kinds
            )
            found = self._candidates[req] = [
                k for k in kinds if problem(req, k.facts, k.tags) is None
            ]
        return list(found)

    def assign(self, job: Job, attempts: Mapping[str, int] | None) -> None:
        """Give ``job`` up to ``job.left`` free printers, best first."""
        judged: dict[int, tuple[str, ...] | None] = {}  # id(kind) -> warnings; None: refused

        def accepted(kind: Kind) -> bool:
            if id(kind) not in judged:
                verdict = self.memo.verdict(job.file, kind.facts, kind.key)
                ok = accepts(verdict, job.allow_mismatch)
                judged[id(kind)] = warning_texts(verdict) if ok else None
            return judged[id(kind)] is not None

        pinned = job.requirements.printer
        if pinned:  # one printer at most: it takes one job per round
            p, kind = self.free_by_id.get(pinned, (None, None))
            if (
                p is not None and kind is not None and self.usable_printer(p)
                and problem(job.requirements, kind.facts, kind.tags) is None and accepted(kind)
            ):  # fmt: skip
                self._take(job, p, judged[id(kind)] or ())
            return
        kinds = self.candidates(job.requirements)
        for _ in range(job.left):
            choice = (
                self._retry_choice(kinds, attempts, accepted)
                if attempts
                else self._best(kinds, accepted)
            )
            if choice is None:
                return
            self._take(job, choice[0], judged[id(choice[1])] or ())

    def _best(
        self, kinds: list[Kind], accepted: Callable[[Kind], bool]
    ) -> tuple[PrinterSnapshot, Kind] | None:
        """The best usable printer among ``kinds``. A kind is validated only when its best
        printer would win, so a job that fits the least-worn printer costs one verdict;
        refused kinds leave ``kinds``."""
        while True:
            best: tuple[int, PrinterSnapshot, Kind] | None = None
            for kind in kinds:
                head = self.head(kind)
                if head is not None and (best is None or head[0] < best[0]):
                    best = (head[0], head[1], kind)
            if best is None:
                return None
            if accepted(best[2]):
                return best[1], best[2]
            kinds.remove(best[2])

    def _retry_choice(
        self, kinds: list[Kind], attempts: Mapping[str, int], accepted: Callable[[Kind], bool]
    ) -> tuple[PrinterSnapshot, Kind] | None:
        """For a job that failed before: the printer that ran it the fewest times, then the
        least worn (rare, so every accepted printer is looked at)."""
        options = [
            (attempts.get(p.id, 0), rank, p, kind)
            for kind in kinds if accepted(kind)
            for rank, p in kind.queue if self.usable_printer(p)
        ]  # fmt: skip
        best = min(options, key=lambda o: o[:2], default=None)
        return None if best is None else (best[2], best[3])

    def _take(self, job: Job, p: PrinterSnapshot, warnings: tuple[str, ...]) -> None:
        self.taken[p.id] = job.id
        self.assignments.append(Assignment(job.id, p.id, warnings))
        self.usable -= 1
        if p.id in self.drawing:
            return
        group = p.power_group
        self.drawing.add(p.id)
        self.idle_in[group] -= 1
        self.power[group] = self.power.get(group, 0) + 1
        if self.full(group):
            self.usable -= self.idle_in[group]
            self.idle_in[group] = 0


def _wear(p: PrinterSnapshot) -> tuple[float, bool, float, str]:
    """Wear-levelling order: least print time, then never used, then least recently used,
    then id."""
    last = p.last_used
    return (p.usage_seconds, last is not None, 0.0 if last is None else last.timestamp(), p.id)
