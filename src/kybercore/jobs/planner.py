"""One dispatch round: which queued job goes to which printer now. Pure: no I/O, no clock.

Which printer may take which job is :mod:`kybercore.jobs.eligibility`.

Jobs go in queue order (priority, then position, then id), each up to the copies it has
left. Among the printers that may take a job the least worn goes first: the least print
time in the usage window, then the least recently used, then the id. For a job that failed
before, printers that ran it fewer times go first. A power group may have at most K
printers heating at once, starts in progress included.

Speed (``bench/dispatch.py``: 5,000 printers, 10,000 jobs): free printers that validation
judges alike (same facts) form a kind, validated once per file; the kinds sit in a heap by
their least-worn printer, shared by the jobs with the same requirements; a kind is validated
only when its best printer would win; verdicts are kept in a :class:`Memo` between rounds;
and the round stops once no printer can take anything.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from itertools import pairwise

from kybercore.core.validation import PrinterFacts
from kybercore.jobs.eligibility import (
    FactsKey,
    Memo,
    PrinterSnapshot,
    clock,
    facts_key,
    normal_tags,
    problem,
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


def in_order(jobs: Sequence[Job]) -> bool:
    """Whether ``jobs`` are in queue order already (checked without building keys)."""
    for a, b in pairwise(jobs):
        if a.priority != b.priority:
            if a.priority < b.priority:
                return False
        elif a.position > b.position or (a.position == b.position and a.id > b.id):
            return False
    return True


def placeable(job: Job) -> bool:
    """Whether a round may place ``job``: queued, with copies left to print."""
    return job.state == "queued" and job.left > 0


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
    queued = [j for j in jobs if placeable(j)]
    if not in_order(queued):  # the store lists them in order; sorting anyway costs more
        queued.sort(key=job_order)
    if paused:
        held = line(QUEUE, "queue_paused")
        return Plan([], {j.id: [held] for j in queued})
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


Tagged = tuple[int, PrinterSnapshot, frozenset[str]]
"""A free printer in a kind: its wear rank (0 = least worn), itself, its tags."""


@dataclass(eq=False)
class Kind:
    """Free printers that validation judges alike (same :func:`facts_key`), least worn
    first. A job that needs tags sees only the printers that have them."""

    facts: PrinterFacts
    key: FactsKey
    printers: list[Tagged] = field(default_factory=list)
    cursors: dict[frozenset[str], int] = field(default_factory=dict)
    """Required tags -> index of the first printer that may still take a job needing them.
    Printers only ever leave a round (taken, or their group full), so cursors only move
    forward and a round walks each list at most once per set of tags."""


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
        self.taken: set[str] = set()
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
        self.free_by_id: dict[str, tuple[Tagged, Kind]] = {}
        self.idle_in: dict[str, int] = {}
        """Power group -> free printers not taken that would start heating."""
        by_key: dict[FactsKey, Kind] = {}
        tag_sets: dict[tuple[str, ...], frozenset[str]] = {}
        for rank, p in enumerate(free):
            tags = tag_sets.get(p.tags)
            if tags is None:
                tags = tag_sets[p.tags] = normal_tags(p.tags)
            key = facts_key(p.facts)
            kind = by_key.get(key)
            if kind is None:
                kind = by_key[key] = Kind(p.facts, key)
                self.kinds.append(kind)
            entry = (rank, p, tags)
            kind.printers.append(entry)
            self.free_by_id[p.id] = (entry, kind)
            if p.id not in self.drawing:
                self.idle_in[p.power_group] = self.idle_in.get(p.power_group, 0) + 1
        self.usable = len(free) - sum(n for g, n in self.idle_in.items() if self.full(g))
        """Free printers left that could still take a job this round."""
        self._candidates: dict[Requirements, tuple[list[Kind], frozenset[str]]] = {}
        self._heaps: dict[Requirements, list[tuple[int, int, Kind]]] = {}
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

    def head(self, kind: Kind, tags: frozenset[str]) -> Tagged | None:
        """The least-worn printer of ``kind`` with ``tags`` that may still take a job."""
        printers, i = kind.printers, kind.cursors.get(tags, 0)
        taken, drawing, power, budget = self.taken, self.drawing, self.power, self.budget
        while i < len(printers):
            _, p, have = printers[i]
            if (
                tags <= have
                and p.id not in taken
                and (budget is None or p.id in drawing or power.get(p.power_group, 0) < budget)
            ):  # the inside of usable_printer: this loop is the round's hottest
                break
            i += 1
        kind.cursors[tags] = i
        return printers[i] if i < len(printers) else None

    def candidates(self, req: Requirements) -> tuple[list[Kind], frozenset[str]]:
        """Kinds whose facts meet ``req``, and the tags a printer of them must have."""
        found = self._candidates.get(req)
        if found is None:
            kinds = (
                self.by_material.get(req.material.strip().casefold(), [])
                if req.material
                else self.kinds
            )
            untagged = replace(req, tags=(), printer=None)
            found = self._candidates[req] = (
                [k for k in kinds if problem(untagged, k.facts, frozenset()) is None],
                normal_tags(req.tags),
            )
        return found

    def assign(self, job: Job, attempts: Mapping[str, int] | None) -> None:
        """Give ``job`` up to ``job.left`` free printers, least worn first."""
        file, allow = job.file, job.allow_mismatch

        def judge(kind: Kind) -> tuple[str, ...] | None:
            """The warnings of starting the job on ``kind`` (None: it may not start)."""
            return self.memo.warnings(file, kind.facts, kind.key, allow)

        pinned = job.requirements.printer
        if pinned:  # one printer at most: it takes one job per round
            entry, kind = self.free_by_id.get(pinned, (None, None))
            if (
                entry is not None and kind is not None and self.usable_printer(entry[1])
                and problem(job.requirements, kind.facts, entry[2]) is None
                and (warnings := judge(kind)) is not None
            ):  # fmt: skip
                self._take(job, entry[1], warnings)
            return
        kinds, tags = self.candidates(job.requirements)
        if attempts:
            self._assign_retried(job, kinds, tags, attempts, judge)
            return
        # The kinds by their least-worn printer; a kind is validated only when that printer
        # would win, so a job that fits it costs one verdict.
        heap = self._heap(job.requirements, kinds, tags)
        refused: list[tuple[int, int, Kind]] = []
        need = job.left
        while need > 0 and heap:
            rank, i, kind = heap[0]
            head = self.head(kind, tags)
            if head is None:  # no printer of it left for these tags, this round
                heapq.heappop(heap)
            elif head[0] != rank:  # its printer went to an earlier job: requeue the kind
                heapq.heapreplace(heap, (head[0], i, kind))
            elif (warnings := judge(kind)) is None:
                refused.append(heapq.heappop(heap))
            else:
                self._take(job, head[1], warnings)
                need -= 1
        for item in refused:  # refused by this job's file only: the next job may take it
            heapq.heappush(heap, item)

    def _heap(
        self, req: Requirements, kinds: list[Kind], tags: frozenset[str]
    ) -> list[tuple[int, int, Kind]]:
        """The kinds meeting ``req`` by their least-worn printer, shared by the jobs with
        the same requirements (entries whose printer was taken are refreshed lazily)."""
        heap = self._heaps.get(req)
        if heap is None:
            heads = ((self.head(kind, tags), i, kind) for i, kind in enumerate(kinds))
            heap = self._heaps[req] = [(h[0], i, kind) for h, i, kind in heads if h is not None]
            heapq.heapify(heap)
        return heap

    def _assign_retried(
        self,
        job: Job,
        kinds: list[Kind],
        tags: frozenset[str],
        attempts: Mapping[str, int],
        judge: Callable[[Kind], tuple[str, ...] | None],
    ) -> None:
        """A job that failed before: the printers that ran it the fewest times first, then
        the least worn (rare, so every accepted printer is looked at)."""
        options = sorted(
            (attempts.get(p.id, 0), rank, p, warnings)
            for kind in kinds if (warnings := judge(kind)) is not None
            for rank, p, have in kind.printers[kind.cursors.get(tags, 0):] if tags <= have
        )  # fmt: skip
        need = job.left
        for _, _, p, warnings in options:
            if need == 0:
                return
            if self.usable_printer(p):  # taken, or the heating budget filled up on the way
                self._take(job, p, warnings)
                need -= 1

    def _take(self, job: Job, p: PrinterSnapshot, warnings: tuple[str, ...]) -> None:
        self.taken.add(p.id)
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
