"""Replaying or double-feeding Moonraker's history never duplicates a job and never takes
a finished job back: Hypothesis draws how live events (repeated, lost, late) and backfill
pages taken at any moment interleave and batch, against the real databases."""

from __future__ import annotations

import asyncio
import itertools
from dataclasses import dataclass

from hypothesis import given, settings
from hypothesis import strategies as st
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import open_database
from kybercore.ledger.history import HistoryJob, HistoryStore, backfill, parse_job
from kybercore.ledger.tables import history_jobs

OUTCOMES = ("completed", "cancelled", "error", "klippy_shutdown")
T0 = 1_767_225_600.0


def version(number: int, outcome: str | None) -> HistoryJob:
    """Job ``number`` as Moonraker reports it when added (outcome None) or finished."""
    parsed = parse_job(
        {
            "job_id": f"{number:06X}",
            "filename": f"part-{number}.gcode",
            "status": outcome or "in_progress",
            "start_time": T0 + number * 60,
            "end_time": None if outcome is None else T0 + number * 60 + 30,
            "print_duration": 0.0 if outcome is None else 25.0 + number,
            "filament_used": 0.0 if outcome is None else 100.0 * number,
        }
    )
    assert parsed is not None
    return parsed


@dataclass(frozen=True)
class Scenario:
    """Moonraker's truth (job k: added, then finished with ``outcomes[k]``, one job after
    the other) and what the ledger was fed: each step is a live event (index into the
    truth's events, possibly repeated, possibly never) or a backfill of the history as it
    stood after that many events; steps are written in ``batches``."""

    outcomes: tuple[str, ...]
    steps: tuple[tuple[str, int], ...]
    batches: tuple[int, ...]

    def events(self) -> list[HistoryJob]:
        return [
            v
            for k, outcome in enumerate(self.outcomes, 1)
            for v in (version(k, None), version(k, outcome))
        ]

    def history_after(self, count: int) -> list[HistoryJob]:
        """Moonraker's history list, newest first, once ``count`` events happened."""
        latest: dict[int, HistoryJob] = {}
        for event in self.events()[:count]:
            latest[event.number] = event
        return [latest[n] for n in sorted(latest, reverse=True)]


@st.composite
def scenarios(draw: st.DrawFn) -> Scenario:
    outcomes = tuple(draw(st.lists(st.sampled_from(OUTCOMES), min_size=1, max_size=6)))
    events = 2 * len(outcomes)
    step = st.one_of(
        st.tuples(st.just("live"), st.integers(0, events - 1)),
        st.tuples(st.just("backfill"), st.integers(0, events)),
    )
    steps = tuple(draw(st.lists(step, min_size=1, max_size=20)))
    batches = tuple(draw(st.lists(st.integers(1, 5), min_size=len(steps), max_size=len(steps))))
    return Scenario(outcomes, steps, batches)


async def play(engine: AsyncEngine, printer: str, scenario: Scenario) -> None:
    store = HistoryStore(engine)
    events = scenario.events()
    fed: list[HistoryJob] = []
    pending: list[HistoryJob] = []
    for (kind, index), batch in zip(scenario.steps, scenario.batches, strict=True):
        if kind == "live":
            pending.append(events[index])
        else:
            history = scenario.history_after(index)

            async def page(limit: int, start: int, history: list[HistoryJob] = history) -> dict:
                chunk = history[start : start + limit]
                return {"count": len(chunk), "jobs": [_raw(j) for j in chunk]}

            # Where it stops depends on what is written so far, as after a reconnect.
            floor = await store.floor(printer, "i")
            async for found in backfill(page, floor, limit=3):
                pending.extend(found)
        if batch % 2 == 0 or len(fed) + len(pending) >= 4 * batch:
            while pending:  # live events and pages are written in batches of any size
                chunk, pending = pending[:batch], pending[batch:]
                await store.upsert([(printer, "i", job) for job in chunk])
                fed.extend(chunk)
    await store.upsert([(printer, "i", job) for job in pending])
    fed.extend(pending)

    # Each job fed is one row, finished if any finished copy of it was fed.
    expected: dict[str, str] = {}
    for job in fed:
        if job.status != "in_progress" or job.job_id not in expected:
            expected[job.job_id] = job.status
    h = history_jobs.c
    async with engine.connect() as conn:
        stored = (
            await conn.execute(select(h.moonraker_job_id, h.status).where(h.printer == printer))
        ).all()
    assert sorted(tuple(r) for r in stored) == sorted(expected.items()), scenario


def _raw(job: HistoryJob) -> dict[str, object]:
    return {
        "job_id": job.job_id, "filename": job.filename, "status": job.status,
        "start_time": job.start_time, "end_time": job.end_time,
        "print_duration": job.print_duration, "filament_used": job.filament_used,
    }  # fmt: skip


def test_interleaved_replays_and_backfills_never_duplicate(database_url: str) -> None:
    # Hypothesis drives a plain function: each example runs on one event loop kept for
    # the whole test, on one migrated database, under a printer name of its own.
    with asyncio.Runner() as runner:
        engine = runner.run(open_database(database_url))
        names = (f"p{n}" for n in itertools.count())

        @given(scenarios())
        @settings(max_examples=150, database=None)
        def check(scenario: Scenario) -> None:
            runner.run(play(engine, next(names), scenario))

        try:
            check()
        finally:
            runner.run(engine.dispose())
