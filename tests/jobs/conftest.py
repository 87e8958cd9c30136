"""Database fixtures for the queue's tests: the same test runs on SQLite and PostgreSQL.

``database_url`` is parametrized over both: a fresh SQLite file, or a fresh database on a
real PostgreSQL server the session starts once (``postgres_server``, tests/conftest.py).
Other test folders use these fixtures by importing them into their conftest.py. When
PostgreSQL cannot start, its tests skip with the reason, and fail with it on CI
(``CI=true``), where it must run.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import default_database_url, open_database
from kybercore.jobs.models import JobFile, NewJob
from kybercore.jobs.store import JobStore
from tests.db.postgres import PostgresUnavailable, unavailable

BACKENDS = ("sqlite", "postgresql")


@pytest.fixture(params=BACKENDS)
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """A URL to a new, empty database: SQLite, then PostgreSQL."""
    if request.param == "sqlite":
        yield default_database_url(tmp_path)
        return
    server = request.getfixturevalue("postgres_server")
    if isinstance(server, PostgresUnavailable):
        unavailable(str(server))
    url = server.create_database()
    yield url
    server.recycle(url)


@pytest.fixture
async def database(database_url: str) -> AsyncIterator[AsyncEngine]:
    """An engine on ``database_url``, migrated."""
    engine = await open_database(database_url)
    yield engine
    await engine.dispose()


@pytest.fixture
def store(database: AsyncEngine) -> JobStore:
    """A job store on the test's database."""
    return JobStore(database)


def new_job(quantity: int = 1, name: str = "cube.gcode", **options: Any) -> NewJob:
    """A job of ``quantity`` copies of a small file (``options``: NewJob's other fields)."""
    return NewJob(JobFile(sha256="c0ffee" + "0" * 58, name=name, size=1234), quantity, **options)


async def assert_consistent(store: JobStore) -> None:
    """The queue's promises, read back from the database (call it when nothing runs):
    counters match the attempts, one holder per copy, one live attempt per printer, and
    every plate a print ended on stays uncleared until its verdict."""
    gates = await store.gates()
    attempts = await store.attempts()
    for job in await store.jobs(include_finished=True):
        mine = [a for a in attempts if a.job_id == job.id]
        held = [a for a in mine if a.live or (a.state == "completed" and a.verdict is None)]
        good = [a for a in mine if a.state == "completed" and a.verdict == "good"]
        assert job.in_flight == len(held), (job, held)
        printed = [a for a in held if a.state == "completed"]
        assert job.awaiting_clear == len(printed), (job, printed)
        assert job.done == len(good), (job, good)
        copies = [a.copy for a in held + good]
        assert len(copies) == len(set(copies)), f"two attempts hold one copy: {mine}"
        assert 0 <= job.done + job.in_flight <= job.quantity, job
        if job.state != "cancelled":
            assert (job.state == "done") == (job.done == job.quantity), job
    live_printers = [a.printer for a in attempts if a.live]
    assert len(live_printers) == len(set(live_printers)), "two live attempts on one printer"
    by_id = {a.id: a for a in attempts}
    for a in attempts:
        if a.live or (a.state in ("completed", "failed", "cancelled") and a.verdict is None):
            gate = gates[a.printer]
            assert gate.attempt_id == a.id, (a, gate)
            if not a.live:
                assert gate.state != "available", (a, gate)
    for gate in gates.values():
        if gate.attempt_id is not None:
            held_by = by_id[gate.attempt_id]
            assert held_by.live or held_by.verdict is None, (gate, held_by)
            assert held_by.state != "failed_to_start", (gate, held_by)
        if gate.state == "awaiting_clear":
            assert gate.attempt_id is not None, gate
