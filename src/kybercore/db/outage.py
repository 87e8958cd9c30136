"""A database that stops answering: :class:`DatabaseUnavailable` for whatever the driver
raised (:mod:`kybercore.db.transaction` raises it), and, for the background tasks that meet
it, one line in the log when an outage begins and one when it ends, however often they retry.

A site's ingest worker writes its ledger to the central PostgreSQL across the WAN, so a cut
line is an outage like any other; what was heard meanwhile stays in memory and is written
once the database answers (:mod:`kybercore.ledger.service`).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator
from typing import Final

from sqlalchemy.exc import DBAPIError, SQLAlchemyError
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.errors import DatabaseUnavailable

UNAVAILABLE: Final = (DatabaseUnavailable, SQLAlchemyError)
"""What a background writer retries: the database away, or refusing one statement."""


@contextlib.contextmanager
def answering(engine: AsyncEngine) -> Iterator[None]:
    """Raise :class:`DatabaseUnavailable` for a database that could not be reached or whose
    connection was lost, whatever the driver raised; a statement's own error (a unique
    violation, "database is locked") passes unchanged."""
    try:
        yield
    except (DBAPIError, OSError, TimeoutError) as exc:
        if not _unreachable(exc):
            raise
        shown = engine.url.render_as_string(hide_password=True)
        cause = exc.orig if isinstance(exc, DBAPIError) else exc
        raise DatabaseUnavailable(
            f"The database {shown} does not answer ({type(cause).__name__}: {cause}). Check "
            "that it runs and that KyberCore can reach it, then try again; a change asked just "
            "as it went away may or may not have been made."
        ) from exc


def _unreachable(exc: DBAPIError | OSError | TimeoutError) -> bool:
    # asyncpg's connect raises plain socket errors and timeouts, which SQLAlchemy passes on
    # unwrapped (a refused connection is a ConnectionRefusedError); a connection lost later
    # is a DBAPIError that invalidated it.
    if isinstance(exc, DBAPIError):
        return exc.connection_invalidated
    return True


class Outage:
    """One background task's view of what it depends on (the database, mostly): failing
    since when, said when it begins (and again for each other kind of failure meanwhile,
    which is news) and once when it ends, however often the task retries."""

    def __init__(self, log: logging.Logger, doing: str, meanwhile: str) -> None:
        """``doing``: what the task cannot do ("write the job history"); ``meanwhile``: what
        becomes of its work ("the jobs heard meanwhile are kept and written once it can")."""
        self._log = log
        self._doing = doing
        self._meanwhile = meanwhile
        self._since: float | None = None
        self._said: set[type[BaseException]] = set()

    def failed(self, exc: BaseException) -> None:
        """The task's work failed with ``exc``."""
        if self._since is None:
            self._since = time.monotonic()
        if type(exc) not in self._said:
            self._said.add(type(exc))
            self._log.warning("cannot %s (%s); %s.", self._doing, said(exc), self._meanwhile)

    def ended(self) -> None:
        """The task's work succeeded."""
        if self._since is not None:
            self._log.info(
                "can %s again (it could not for %.0f s)",
                self._doing, time.monotonic() - self._since,
            )  # fmt: skip
            self._since = None
            self._said.clear()


def said(exc: BaseException) -> str:
    """``exc`` in a line for a log; a database away by its driver's own error."""
    away = isinstance(exc, DatabaseUnavailable)
    cause = exc.__cause__ if away and exc.__cause__ is not None else exc
    if isinstance(cause, DBAPIError) and cause.orig is not None:
        cause = cause.orig
    return f"{'the database does not answer: ' if away else ''}{type(cause).__name__}: {cause}"
