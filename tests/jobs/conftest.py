"""Database fixtures for the queue's tests: the same test runs on SQLite and PostgreSQL.

``database_url`` is parametrized over both: a fresh SQLite file, or a fresh database on a
real PostgreSQL server this session starts (:mod:`tests.db.postgres`). Other test folders
use these fixtures by importing them into their conftest.py. When PostgreSQL cannot start,
its tests skip with the reason, and fail with it on CI (``CI=true``), where it must run.
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import default_database_url, open_database
from kybercore.jobs.store import JobStore
from tests.db.postgres import PostgresServer, PostgresUnavailable

BACKENDS = ("sqlite", "postgresql")


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[PostgresServer | PostgresUnavailable]:
    """The session's PostgreSQL server, started the first time a test asks for one (or why
    it could not start)."""
    try:
        server = PostgresServer()
    except PostgresUnavailable as exc:
        yield exc
        return
    try:
        server.start()
    except PostgresUnavailable as exc:
        server.stop()
        yield exc
        return
    yield server
    server.stop()


def unavailable(reason: str) -> None:
    """Fail on CI, where PostgreSQL must run; skip elsewhere."""
    if os.environ.get("CI") == "true":
        pytest.fail(f"PostgreSQL is required on CI: {reason}")
    pytest.skip(f"PostgreSQL unavailable: {reason}")


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
    server.drop_database(url)


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
