"""A hypothesis state machine over the job store, on SQLite and on PostgreSQL.

Random jobs, reservations on random printers from two engines (two processes' worth of
connections, also at the same moment), attempts moved on and ended every way, plates
cleared good and bad, printers held and released, jobs cancelled and requeued, the queue
paused. After every step the books must hold (:func:`assert_consistent`): one holder per
copy, in flight ≤ quantity − done, done ≤ quantity, a plate a print ended on uncleared
until its verdict; and a printer that was not free never gets a new attempt.
"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any, ClassVar, TypeVar

from hypothesis import Phase, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    Bundle,
    RuleBasedStateMachine,
    invariant,
    precondition,
    rule,
    run_state_machine_as_test,
)
from sqlalchemy import delete
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import open_database
from kybercore.errors import ActionRejected
from kybercore.jobs import tables
from kybercore.jobs.models import ENDED, LIVE, Attempt, Gate, Job
from kybercore.jobs.store import JobStore
from tests.jobs.conftest import assert_consistent, new_job

T = TypeVar("T")
PRINTERS = ("p1", "p2", "p3", "p4")
PICK = st.integers(0, 63)
VIA = st.integers(0, 1)  # which engine: two processes on one database
VERDICTS = st.sampled_from(["good", "bad"])
# Mostly completed, as most prints are; every other end too.
ENDS = st.sampled_from(["completed", "completed", "completed", *sorted(ENDED - {"completed"})])
# No shrinking: racing reservations make a replay differ from the run it replays, so
# shrinking a failure would take minutes and end "flaky"; the failing run's steps are
# reported as they were.
SETTINGS = settings(
    max_examples=25,
    stateful_step_count=40,
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
)
_RANK = {"pending": 0, "uploading": 1, "starting": 2, "printing": 3, "paused": 3}


class StoreMachine(RuleBasedStateMachine):
    """One run: an empty queue, two engines on one database."""

    loop: ClassVar[asyncio.AbstractEventLoop]
    engines: ClassVar[tuple[AsyncEngine, AsyncEngine]]
    jobs = Bundle("jobs")

    def __init__(self) -> None:
        super().__init__()
        self.stores = tuple(JobStore(engine) for engine in self.engines)
        self.run(_wipe(self.engines[0]))
        # What the database said after the last step (read by the invariant).
        self.attempts: list[Attempt] = []
        self.gates: dict[str, Gate] = {}
        self.queue: list[Job] = []
        self.failures: dict[int, int] = {}  # per job, since it was created or requeued

    def run(self, work: Coroutine[Any, Any, T]) -> T:
        return self.loop.run_until_complete(work)

    def free(self, printer: str) -> bool:
        gate = self.gates.get(printer)
        return gate is None or (gate.state == "available" and gate.attempt_id is None)

    def live(self) -> list[Attempt]:
        return [a for a in self.attempts if a.live]

    def plate(self, printer: str) -> Attempt | None:
        """The ended attempt whose plate ``printer`` still holds."""
        gate = self.gates.get(printer)
        return next(
            (a for a in self.attempts if gate and a.id == gate.attempt_id and not a.live), None
        )

    def held(self) -> list[str]:
        return [p for p, g in self.gates.items() if g.state in ("held", "maintenance")]

    # -- the path that prints ----------------------------------------------------------------

    @rule(target=jobs, quantity=st.integers(1, 3), max_attempts=st.integers(1, 3))
    def create_job(self, quantity: int, max_attempts: int) -> int:
        job = self.run(self.stores[0].create_job(new_job(quantity, max_attempts=max_attempts), "t"))
        self.failures[job.id] = 0
        return job.id

    @rule(
        printer=st.sampled_from(PRINTERS), pick=PICK, end=ENDS,
        verdict=VERDICTS, via=VIA,
    )  # fmt: skip
    def progress(self, printer: str, pick: int, end: str, verdict: str, via: int) -> None:
        """The next thing in one printer's life, as a dispatcher and an operator would do
        it: reserve a waiting job, print, end the print, clear the plate, release it."""
        store = self.stores[via]
        running = next((a for a in self.live() if a.printer == printer), None)
        if running is not None and running.state != "printing":
            self.run(store.advance(running.id, "printing"))
        elif running is not None:
            self.end(running, end, via)
        elif self.plate(printer) is not None:
            self.run(store.clear(printer, verdict, user="t"))  # type: ignore[arg-type]
        elif printer in self.held():
            self.run(store.release(printer, "t"))
        else:
            waiting = [j.id for j in self.queue if j.state == "queued" and j.left > 0]
            job = _pick(waiting, pick)
            if job is not None:
                assert self.run(store.reserve(job, printer)) is not None

    def end(self, attempt: Attempt, state: str, via: int) -> None:
        gate = self.gates[attempt.printer]
        self.run(self.stores[via].finish(attempt.id, state, reason="r"))  # type: ignore[arg-type]
        if state in ("failed", "failed_to_start"):
            self.failures[attempt.job_id] += 1
        after = self.run(self.stores[0].gate(attempt.printer))
        # A failed start holds the printer with nothing on it; any other end leaves its
        # plate to clear, and a hold set meanwhile stays.
        kept = gate.state != "available"
        if state == "failed_to_start":
            assert (after.state, after.attempt_id) == (gate.state if kept else "held", None)
        else:
            assert after.attempt_id == attempt.id
            assert after.state == (gate.state if kept else "awaiting_clear")

    # -- everything else, refusals included -------------------------------------------------

    @rule(job=jobs, printer=st.sampled_from(PRINTERS), via=VIA)
    def reserve(self, job: int, printer: str, via: int) -> None:
        attempt = self.run(self.stores[via].reserve(job, printer))
        if not self.free(printer):
            assert attempt is None, f"{printer} was not free: {self.gates[printer]}"

    @rule(picks=st.lists(st.tuples(st.sampled_from(PRINTERS), VIA, PICK), min_size=2, max_size=8))
    @precondition(lambda self: bool(self.failures))
    def reserve_at_once(self, picks: list[tuple[str, int, int]]) -> None:
        """Several reservations at the same moment, from both engines."""
        job_ids = sorted(self.failures)
        calls = [
            self.stores[via].reserve(job_ids[pick % len(job_ids)], printer)
            for printer, via, pick in picks
        ]
        new = [a for a in self.run(_gather(calls)) if a is not None]
        for attempt in new:
            assert self.free(attempt.printer), f"{attempt.printer} was not free"
        printers = [a.printer for a in new]
        assert len(printers) == len(set(printers)), f"one printer got two attempts: {new}"

    @rule(pick=PICK, state=st.sampled_from(sorted(LIVE)), via=VIA)
    def advance(self, pick: int, state: str, via: int) -> None:
        attempt = _pick(self.live(), pick)
        if attempt is None:
            return
        forward = _RANK[state] > _RANK[attempt.state] or {state, attempt.state} == {
            "printing",
            "paused",
        }
        try:
            moved = self.run(self.stores[via].advance(attempt.id, state))  # type: ignore[arg-type]
        except ActionRejected:
            assert not forward
            assert state != attempt.state
        else:
            assert forward or state == attempt.state
            assert moved.state == state

    @rule(pick=PICK, state=st.sampled_from(sorted(ENDED)), via=VIA)
    def finish(self, pick: int, state: str, via: int) -> None:
        attempt = _pick(self.live(), pick)
        if attempt is not None:
            self.end(attempt, state, via)

    @rule(
        printer=st.sampled_from(PRINTERS),
        action=st.sampled_from(["good", "bad", "held", "maintenance", "release"]),
        via=VIA,
    )
    def operator(self, printer: str, action: str, via: int) -> None:
        """Clear a plate good or bad, hold a printer, put it in maintenance, release it:
        refused when there is no plate to clear or nothing to release."""
        store = self.stores[via]
        if action in ("good", "bad"):
            uncleared = self.plate(printer) is not None
            try:
                self.run(store.clear(printer, action, user="t"))  # type: ignore[arg-type]
            except ActionRejected:
                assert not uncleared
            else:
                assert uncleared
        elif action == "release":
            try:
                self.run(store.release(printer, "t"))
            except ActionRejected:
                assert printer not in self.held()
        elif len(self.held()) < 2:  # leave printers to print on
            if action == "held":
                self.run(store.hold(printer, "h", "t"))
            else:
                self.run(store.set_maintenance(printer, "m", "t"))

    @rule(
        job=jobs,
        printer=st.sampled_from(PRINTERS),
        action=st.sampled_from(["cancel", "requeue", "pause"]),
    )
    def manage(self, job: int, printer: str, action: str) -> None:
        """Cancel a job (refused when done), requeue it (refused unless blocked), or pause
        the queue for a moment (nothing is reserved meanwhile)."""
        store = self.stores[0]
        if action == "cancel":
            try:
                _, live = self.run(store.cancel_job(job, "t"))
            except ActionRejected:
                assert self.run(store.job(job)).state == "done"
            else:
                mine = sorted(a.id for a in self.live() if a.job_id == job)
                assert sorted(a.id for a in live) == mine
        elif action == "requeue":
            try:
                self.run(store.requeue_job(job, "t"))
            except ActionRejected:
                assert self.run(store.job(job)).state != "blocked"
            else:
                self.failures[job] = 0
        else:
            self.run(store.set_queue_paused(True, "t"))
            assert self.run(self.stores[1].queue_paused())
            assert self.run(self.stores[1].reserve(job, printer)) is None
            self.run(self.stores[1].set_queue_paused(False, "t"))

    # -- invariants --------------------------------------------------------------------------

    @invariant()
    def books_hold(self) -> None:
        store = self.stores[1]
        self.run(assert_consistent(store))
        self.attempts = self.run(store.attempts())
        self.gates = self.run(store.gates())
        self.queue = self.run(store.jobs(include_finished=True))
        for job in self.queue:
            assert job.failures == self.failures[job.id], job
            blocked = (
                job.state != "cancelled"
                and job.done < job.quantity
                and job.failures >= job.max_attempts
            )
            assert (job.state == "blocked") == blocked, job


def test_the_store_keeps_its_promises_under_random_steps(database_url: str) -> None:
    loop = asyncio.new_event_loop()
    try:
        engines = loop.run_until_complete(
            _gather([open_database(database_url), open_database(database_url)])
        )
        StoreMachine.loop = loop
        StoreMachine.engines = (engines[0], engines[1])
        run_state_machine_as_test(StoreMachine, settings=SETTINGS)
    finally:
        for engine in getattr(StoreMachine, "engines", ()):
            loop.run_until_complete(engine.dispose())
        loop.close()


async def _gather(calls: list[Coroutine[Any, Any, T]]) -> list[T]:
    return list(await asyncio.gather(*calls))


async def _wipe(engine: AsyncEngine) -> None:
    async with engine.begin() as conn:
        for table in (tables.gates, tables.queue_events, tables.attempts, tables.jobs):
            await conn.execute(delete(table))
        await conn.execute(delete(tables.settings))


def _pick(candidates: list[T], index: int) -> T | None:
    # Draws must not depend on the database's state: which of two racing reservations
    # wins differs from run to run, and hypothesis replays a run's draws to shrink it.
    return candidates[index % len(candidates)] if candidates else None
