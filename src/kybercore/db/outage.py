"""A database that stops answering, as the background writers meet it: what it raises, and
one line in the log when an outage begins and one when it ends, however often they retry.

A site's ingest worker writes its ledger to the central PostgreSQL across the WAN, so a cut
line is an outage like any other; what was heard meanwhile stays in memory and is written
once the database answers (:mod:`kybercore.ledger.service`).
"""

from __future__ import annotations

import logging
import time
from typing import Final

from sqlalchemy.exc import SQLAlchemyError

UNAVAILABLE: Final = (SQLAlchemyError, OSError, TimeoutError)
"""What a database that cannot be reached raises: SQLAlchemy's errors, and the socket
errors and connect timeouts of asyncpg's connect, which SQLAlchemy passes on unwrapped (a
refused connection is a ConnectionRefusedError)."""


class Outage:
    """One background task's view of the database: away since when, said once."""

    def __init__(self, log: logging.Logger, doing: str, meanwhile: str) -> None:
        """``doing``: what the task cannot do ("write the job history"); ``meanwhile``: what
        becomes of its work ("the jobs heard meanwhile are kept and written once it does")."""
        self._log = log
        self._doing = doing
        self._meanwhile = meanwhile
        self._since: float | None = None

    def failed(self, exc: BaseException) -> None:
        """The task's database work failed with ``exc`` (one of :data:`UNAVAILABLE`)."""
        if self._since is None:
            self._since = time.monotonic()
            self._log.warning(
                "cannot %s: the database does not answer (%s: %s); %s. Check that it runs "
                "and is reachable from here.",
                self._doing, type(exc).__name__, exc, self._meanwhile,
            )  # fmt: skip

    def ended(self) -> None:
        """The task's database work succeeded."""
        if self._since is not None:
            self._log.info(
                "the database answers again (for %.0f s it could not %s)",
                time.monotonic() - self._since, self._doing,
            )  # fmt: skip
            self._since = None
