"""The ledger an ingest worker keeps: the job history and state timeline of the printers it
acts for, in the database the fronts read (:class:`~kybercore.ledger.service.LedgerService`).

A site's worker writes to the central PostgreSQL across the WAN. Restarted while that
database does not answer (a cut line, the server down), it holds its printers anyway and
starts its ledger once the database answers: printers held matter more than their history
meanwhile, which mostly comes back (the jobs, from each printer's Moonraker history). On a
worker's first start the same failure stops it instead, saying why: a wrong address is
likelier then than an outage.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Final

from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.aio import cancel_and_wait
from kybercore.db import open_database
from kybercore.db.outage import Outage
from kybercore.errors import ConfigError, DatabaseUnavailable
from kybercore.fleet.service import FleetService
from kybercore.ledger.service import LedgerService

log = logging.getLogger(__name__)

RETRY_SECONDS: Final = 5.0
"""How often a worker started without its database tries it again."""


class WorkerLedger:
    """:meth:`start`, then :meth:`stop`; :attr:`ledger` once the database answered."""

    def __init__(
        self, service: FleetService, url: str, owns: Callable[[str], bool], unwritten: Path
    ) -> None:
        """``owns(printer_id)``: whether the worker acts for the printer now; ``unwritten``:
        the file that keeps the state changes a stop could not write."""
        self._service = service
        self._url = url
        self._owns = owns
        self._unwritten = unwritten
        self.ledger: LedgerService | None = None
        self._engine: AsyncEngine | None = None
        self._waiting: asyncio.Task[None] | None = None

    async def start(self, *, restarted: bool) -> None:
        """Open the database and start the ledger. ``restarted``: the worker ran before;
        then a database that does not answer is waited for in the background. Otherwise
        that raises :class:`ConfigError`, as any other database error does."""
        try:
            await self._open()
        except ConfigError as exc:
            if not restarted or not isinstance(exc.__cause__, DatabaseUnavailable):
                raise
            self._waiting = asyncio.create_task(self._open_once_it_answers(exc), name="ledger")

    async def stop(self) -> None:
        """Stop the ledger (writing what it heard) and close the database."""
        await cancel_and_wait(self._waiting)
        if self.ledger is not None:
            await self.ledger.stop()
        if self._engine is not None:
            await self._engine.dispose()

    async def _open(self) -> None:
        engine = await open_database(self._url)
        ledger = LedgerService(self._service, engine, owns=self._owns, unwritten=self._unwritten)
        try:
            await ledger.start()
        except BaseException:
            await engine.dispose()
            raise
        self._engine, self.ledger = engine, ledger

    async def _open_once_it_answers(self, first: ConfigError) -> None:
        outage = Outage(
            log, "open the ledger's database",
            "the printers are held meanwhile; the jobs they finish come back from their "
            "Moonraker history once it can, their state changes until then do not",
        )  # fmt: skip
        outage.failed(_away(first))
        while True:
            await asyncio.sleep(RETRY_SECONDS)
            try:
                await self._open()
            except (ConfigError, DatabaseUnavailable) as exc:
                outage.failed(_away(exc))
            else:
                outage.ended()
                return


def _away(exc: ConfigError | DatabaseUnavailable) -> BaseException:
    # open_database says a database away as a ConfigError with a start-up's advice; here
    # it is an outage, said by the driver's own error.
    cause = exc.__cause__
    return cause if isinstance(cause, DatabaseUnavailable) else exc
