"""One transaction per unit of work, retried when another writer is in the way.

Every change to the queue is one call to :func:`transaction`: it commits when the work
returns and rolls back when it raises, so a write is never half done. On SQLite a write
transaction takes the database's write lock at ``BEGIN IMMEDIATE`` (see
:mod:`kybercore.db.engine`), writers of this process queue on an asyncio lock (no busy
polling between coroutines) and writers of other processes on SQLite's busy timeout. When
the database still says "locked" (SQLite) or picks this transaction as a deadlock victim
or serialization failure (PostgreSQL), the whole work runs again, a bounded number of
times; the work must therefore only touch the database.

A database that cannot be reached raises DatabaseUnavailable here and in :func:`reading`,
whatever the driver raised (:mod:`kybercore.db.outage`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import weakref
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Final, TypeVar

from sqlalchemy.engine import Engine
from sqlalchemy.exc import DBAPIError, IntegrityError
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine

from kybercore.db.outage import answering

log = logging.getLogger(__name__)

T = TypeVar("T")

WRITE_OPTION: Final = "kybercore_write"
"""Execution option that marks a write transaction (SQLite: ``BEGIN IMMEDIATE``)."""
ATTEMPTS: Final = 5
"""Tries of one unit of work before the database's error is raised."""
# PostgreSQL's serialization_failure and deadlock_detected: retry the whole transaction.
_PG_RETRY: Final = frozenset({"40001", "40P01"})
_PG_UNIQUE: Final = "23505"

_writers: weakref.WeakKeyDictionary[Engine, asyncio.Lock] = weakref.WeakKeyDictionary()


async def transaction(
    engine: AsyncEngine,
    work: Callable[[AsyncConnection], Awaitable[T]],
    *,
    write: bool = True,
) -> T:
    """Run ``work`` in one transaction and return what it returns, committed.

    ``write=False`` for reads: on SQLite they neither wait for nor block writers.
    """
    target = engine.execution_options(**{WRITE_OPTION: True}) if write else engine
    for attempt in range(1, ATTEMPTS + 1):
        try:
            with answering(engine):
                async with _serialized(engine, write), target.begin() as conn:
                    return await work(conn)
        except DBAPIError as exc:
            if attempt == ATTEMPTS or not _transient(exc):
                raise
            log.warning("Database busy (%s); trying again (%d/%d)", exc.orig, attempt, ATTEMPTS)
            # Jitter keeps two processes that collided from colliding again in step.
            await asyncio.sleep(random.uniform(0.01, 0.05) * attempt)
    raise AssertionError("unreachable")  # the loop returns or raises


@contextlib.asynccontextmanager
async def reading(engine: AsyncEngine) -> AsyncIterator[AsyncConnection]:
    """A connection for reads outside a transaction of :func:`transaction`'s (a page of the
    history, the statistics); DatabaseUnavailable when the database cannot be reached."""
    with answering(engine):
        async with engine.connect() as conn:
            yield conn


def is_unique_violation(exc: IntegrityError) -> bool:
    """Whether ``exc`` is a unique constraint or index saying no (not a foreign key or a
    check): for an insert that lost a race, the expected outcome."""
    orig = exc.orig
    if getattr(orig, "sqlstate", None) == _PG_UNIQUE:
        return True
    return "UNIQUE constraint failed" in str(orig)


@contextlib.asynccontextmanager
async def _serialized(engine: AsyncEngine, write: bool) -> AsyncIterator[None]:
    # SQLite has one writer at a time anyway; queueing this process's writers here spares
    # them the busy handler's sleep-and-retry. PostgreSQL locks rows: no queue.
    if not write or engine.dialect.name != "sqlite":
        yield
        return
    lock = _writers.setdefault(engine.sync_engine, asyncio.Lock())
    async with lock:
        yield


def _transient(exc: DBAPIError) -> bool:
    if getattr(exc.orig, "sqlstate", None) in _PG_RETRY:
        return True
    message = str(exc.orig)
    return "database is locked" in message or "database is busy" in message
