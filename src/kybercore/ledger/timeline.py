"""Each printer's state over time, as intervals: the basis of utilisation.

:func:`printer_state` names a printer's state from what KyberCore knows of it (pure).
:class:`Timeline` keeps the current state of every printer in memory and writes a row only
when a state changes, in batches (:meth:`Timeline.flush`): a thousand printers sending four
status updates a second cause no writes while their states stay the same.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final, Literal

from sqlalchemy import bindparam, func, or_, select, update
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine

from kybercore.db import transaction
from kybercore.ledger.tables import history_jobs, printer_states

State = Literal[
    "disabled", "offline", "error", "idle", "printing", "paused", "awaiting_clear", "maintenance"
]
STATES: Final[tuple[State, ...]] = (
    "disabled", "offline", "error", "idle", "printing", "paused", "awaiting_clear", "maintenance",
)  # fmt: skip
"""``disabled``: switched off in printers.json (offline by plan). ``offline``: Moonraker or
Klippy cannot be reached. ``error``: Klippy is in shutdown or error. ``awaiting_clear`` and
``maintenance`` come from the queue's gate."""


def printer_state(connection: str, klippy: str, print_state: str, gate: str | None) -> State:
    """The timeline state of one printer.

    ``connection`` and ``klippy`` as the session reports them, ``print_state`` is
    ``print_stats.state``, ``gate`` the queue gate's state (None: no queue). A print running
    wins over the gate; maintenance wins over being unreachable (the printer may be off
    for it); a plate waiting to be cleared shows only on a reachable, ready printer.
    """
    if connection == "disabled":
        return "disabled"
    ready = connection == "online" and klippy == "ready"
    if ready and print_state in ("printing", "paused"):
        return "printing" if print_state == "printing" else "paused"
    if gate == "maintenance":
        return "maintenance"
    if connection != "online" or klippy not in ("ready", "shutdown", "error"):
        return "offline"
    if klippy != "ready":
        return "error"
    return "awaiting_clear" if gate == "awaiting_clear" else "idle"


@dataclass(frozen=True)
class Change:
    """A printer entered ``state`` at ``at`` (None: it left the fleet)."""

    printer: str
    state: State | None
    at: float


class Timeline:
    """The ``printer_states`` table, written only on changes, in batches."""

    def __init__(self, engine: AsyncEngine) -> None:
        self._engine = engine
        self._current: dict[str, State] = {}
        self._pending: list[Change] = []
        self._opened: dict[str, float] = {}
        """Printer -> start of the open interval this timeline wrote."""
        self._unsure: list[Change] = []
        """Pending changes that may be in the table already: a write whose commit went
        through though its reply was lost, or a previous run's (:meth:`take_back`)."""
        self._writing = asyncio.Lock()

    @property
    def current(self) -> dict[str, State]:
        """Every known printer's state now (shared: do not modify)."""
        return self._current

    @property
    def pending(self) -> int:
        """How many changes are noted and not written yet."""
        return len(self._pending)

    def observe(self, printer: str, state: State, at: float | None = None) -> None:
        """Note the printer's state; a change is written with the next :meth:`flush`."""
        if self._current.get(printer) != state:
            self._current[printer] = state
            self._pending.append(Change(printer, state, time.time() if at is None else at))

    def forget(self, printers: Iterable[str], at: float | None = None) -> None:
        """Printers no longer in the fleet: their open interval ends."""
        when = time.time() if at is None else at
        for printer in printers:
            if self._current.pop(printer, None) is not None:
                self._pending.append(Change(printer, None, when))

    def unwritten(self) -> tuple[list[Change], dict[str, float]]:
        """What is noted and not written, and the start of each open interval this
        timeline wrote: what :meth:`take_back` needs to write it in another run."""
        return list(self._pending), dict(self._opened)

    def take_back(self, changes: list[Change], opened: dict[str, float]) -> None:
        """Note again what a previous run could not write (its :meth:`unwritten`), ahead
        of anything noted since; the intervals it opened are ended as it would have. A
        change already in the table is left out at the next :meth:`flush`: that run wrote
        it and was killed before it could say so (its file was kept during an outage and
        not removed yet)."""
        self._pending[:0] = changes
        self._unsure[:0] = changes
        self._opened = {**opened, **self._opened}

    async def flush(self) -> int:
        """Write the changes noted so far in one transaction; how many. When it returns,
        every change noted before the call is in the table (one write at a time)."""
        async with self._writing:
            return await self._flush()

    async def _flush(self) -> int:
        if self._unsure:
            await self._leave_out_written()
        changes, self._pending = self._pending, []
        if not changes:
            return 0
        # Backwards: each interval ends where the printer's next change starts; what is
        # left in `first` is each printer's first change, which ends its open interval.
        first: dict[str, Change] = {}
        rows = []
        for change in reversed(changes):
            if change.state is not None:
                ends = first[change.printer].at if change.printer in first else None
                rows.append(
                    {"printer": change.printer, "state": change.state,
                     "started_at": change.at, "ended_at": ends}
                )  # fmt: skip
            first[change.printer] = change
        rows.reverse()
        # A new state ends the printer's interval it falls in: the open one (a worker taking
        # over from one that died ends the dead one's), or, for a change a stopped run could
        # not write and writes late, the one a successor ended after it (the successor's
        # own, begun later, stay as they are). Leaving ends only the interval this timeline
        # opened (a paused former owner must not end its successor's).
        taken = [{"p": c.printer, "at": c.at} for c in first.values() if c.state is not None]
        left = [
            {"p": c.printer, "at": c.at, "since": self._opened[c.printer]}
            for c in first.values()
            if c.state is None and c.printer in self._opened
        ]

        async def work(conn: AsyncConnection) -> None:
            states = printer_states.c
            open_interval = (states.printer == bindparam("p"), states.ended_at.is_(None))
            ending = update(printer_states).values(ended_at=bindparam("at"))
            if taken:
                falls_in = (
                    states.started_at <= bindparam("at"),
                    or_(states.ended_at.is_(None), states.ended_at > bindparam("at")),
                )
                await conn.execute(ending.where(states.printer == bindparam("p"), *falls_in), taken)
            if left:
                since = states.started_at == bindparam("since")
                await conn.execute(ending.where(*open_interval, since), left)
            if rows:
                await conn.execute(printer_states.insert(), rows)

        write = asyncio.ensure_future(transaction(self._engine, work))
        try:
            await asyncio.shield(write)
        finally:
            # Cancelled while writing (KyberCore stopping): the commit may be under way in
            # the driver's thread and cannot be taken back. Its end says whether the rows
            # are in; taking them again after a commit would write each interval twice.
            if not write.done():
                await asyncio.wait({write})
            if write.cancelled() or write.exception() is not None:
                # Written next time, in order; unless the commit went through and only its
                # reply was lost (the line cut mid-commit): then each would be there twice.
                self._pending[:0] = changes
                self._unsure = changes
            else:
                self._written(changes)
        return len(changes)

    def _written(self, changes: Iterable[Change]) -> None:
        """The table holds ``changes``: follow the intervals this timeline opened."""
        for change in changes:
            if change.state is None:
                self._opened.pop(change.printer, None)
            else:
                self._opened[change.printer] = change.at

    async def _leave_out_written(self) -> None:
        """Take out of the pending changes the unsure ones the table has (a row of the
        same printer begun at the same moment), each on its own: a previous run may have
        written a part. Leaving a printer, written again, ends nothing a second time."""
        unsure = {(c.printer, c.at) for c in self._unsure if c.state is not None}
        if not unsure:
            self._unsure = []
            return
        starts = [at for _, at in unsure]
        s = printer_states.c
        # The rows begun in the changes' span (every printer's: a list of printers as long
        # as a fleet would pass the drivers' limits on bound parameters).
        query = select(s.printer, s.started_at).where(
            s.started_at >= min(starts), s.started_at <= max(starts)
        )

        async def work(conn: AsyncConnection) -> set[tuple[str, float]]:
            return {(row.printer, row.started_at) for row in await conn.execute(query)}

        found = unsure & await transaction(self._engine, work, write=False)
        done: list[Change] = []
        left: list[Change] = []
        for change in self._pending:
            there = change.state is not None and (change.printer, change.at) in found
            (done if there else left).append(change)
        self._written(done)
        self._pending = left
        self._unsure = []

    async def recover(self) -> None:
        """End the intervals a previous run left open (it stopped without :meth:`close`),
        at the last moment that run is known to have been alive: its newest state change
        or history write. The time it was down is in no interval (not observed)."""

        async def work(conn: AsyncConnection) -> None:
            last = max(
                (await conn.scalar(select(func.max(printer_states.c.started_at)))) or 0.0,
                (await conn.scalar(select(func.max(history_jobs.c.updated_at)))) or 0.0,
            )
            states = printer_states.c
            await conn.execute(
                update(printer_states).where(states.ended_at.is_(None)).values(ended_at=last)
            )
            # An interval never ends before it starts.
            await conn.execute(
                update(printer_states)
                .where(states.ended_at < states.started_at)
                .values(ended_at=states.started_at)
            )

        await transaction(self._engine, work)

    async def close(self, at: float | None = None) -> None:
        """Write what is pending and end every open interval (KyberCore is stopping)."""
        self.forget(list(self._current), at)
        await self.flush()
