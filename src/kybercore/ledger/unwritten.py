"""The state changes a ledger could not write (its database did not answer), kept in a
file beside the process's other data and written at its next start.

The jobs heard meanwhile need no such file: they come back from each printer's Moonraker
history. The state changes exist only in the process that saw them: they are kept during
an outage (every :data:`KEEP_EVERY` seconds, so a process killed meanwhile loses at most
those), and at a stop. The file is replaced whole (:func:`~kybercore.files.replace_file`),
removed once its changes are in the database, and taken back idempotently: a run killed
between writing them and removing it does not write them twice.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import os
import time
from pathlib import Path
from typing import Any, Final

from kybercore.db.outage import Outage
from kybercore.files import replace_file
from kybercore.ledger.timeline import STATES, Change, Timeline

log = logging.getLogger(__name__)

VERSION: Final = 1

UNWRITTEN: Final = "ledger-unwritten.json"
"""The file's name in a process's data folder (beside printers.json, or a worker's)."""
NONE_LEFT: Final = "and no state change is left unwritten"
"""How a stop's log ends when every state change seen was written."""


KEEP_EVERY: Final = 10.0
"""Seconds between two saves during an outage (while the changes noted grow)."""


class UnwrittenFile:
    """One ledger's file: :meth:`take_back` at its start, :meth:`keep` while its database
    does not answer, :meth:`written` once it does, :meth:`keep_at_stop`."""

    def __init__(self, path: Path, timeline: Timeline) -> None:
        self.path = path
        self._timeline = timeline
        self._kept_at: float | None = None
        """monotonic() of this run's last save; None: this run has no file out."""
        self._kept_pending = 0
        self._outage = Outage(
            log, f"keep the unwritten state changes in {path}",
            "they are kept in memory only, and lost if this process is killed",
        )  # fmt: skip

    async def take_back(self) -> None:
        """Write what a previous run left, before anything new is heard (this run's changes
        come after it); raises what the database raises, the file kept."""
        left = await asyncio.to_thread(load, self.path)
        if left is None:
            return
        self._timeline.take_back(*left)
        count = await self._timeline.flush()
        await asyncio.to_thread(self.path.unlink, missing_ok=True)
        log.info("wrote the %d state changes a previous run could not (%s)", count, self.path)

    async def keep(self) -> None:
        """The timeline's write failed: save what it holds, unless saved less than
        :data:`KEEP_EVERY` ago or nothing was noted since. A save that fails is said in
        the log (once, not at every try) and tried again next time."""
        pending = self._timeline.pending
        if not pending or pending == self._kept_pending:
            return
        if self._kept_at is not None and time.monotonic() - self._kept_at < KEEP_EVERY:
            return
        try:
            await asyncio.to_thread(save, self.path, self._timeline)
        except OSError as exc:
            self._outage.failed(exc)
            return
        self._outage.ended()
        self._kept_at, self._kept_pending = time.monotonic(), pending

    async def written(self) -> None:
        """The timeline's write succeeded: the file this run kept is out of date."""
        if self._kept_at is not None:
            await asyncio.to_thread(self.path.unlink, missing_ok=True)
            self._kept_at, self._kept_pending = None, 0

    async def keep_at_stop(self) -> str:
        """Save the unwritten changes for the next start, every open interval ended now
        (as the stop's close() would have written); how the log says it."""
        # Also when every change was written: the stop's close() did not run, so the open
        # intervals would otherwise end at the next start's guess (Timeline.recover).
        self._timeline.forget(list(self._timeline.current))
        if not self._timeline.pending:
            await self.written()
            return NONE_LEFT
        try:
            await asyncio.to_thread(save, self.path, self._timeline)
        except OSError as exc:
            return f"the state changes do not: they could not be kept in {self.path} ({exc})"
        return f"the state changes are kept in {self.path} and written then"


def save(path: Path, timeline: Timeline) -> None:
    """Write what ``timeline`` could not (blocking: run it in a thread). Raises OSError."""
    changes, opened = timeline.unwritten()
    changed = [[c.printer, c.state, c.at] for c in changes]
    body = json.dumps({"version": VERSION, "changes": changed, "opened": opened})
    replace_file(path, body.encode())


def load(path: Path) -> tuple[list[Change], dict[str, float]] | None:
    """What a previous run left in ``path`` (blocking: run it in a thread); None when there
    is no file. A file that is not one of these is set aside as ``<name>.bad``, said in
    the log, and None returned: a start is not refused for the history of a previous run."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    try:
        return _parse(json.loads(text))
    except (ValueError, TypeError, KeyError) as exc:
        bad = path.with_name(path.name + ".bad")
        os.replace(path, bad)
        log.warning(
            "%s is not a list of unwritten state changes (%s); set aside as %s, its changes "
            "are not in the timeline",
            path, exc, bad,
        )  # fmt: skip
        return None


def _parse(data: Any) -> tuple[list[Change], dict[str, float]]:
    if not isinstance(data, dict) or data.get("version") != VERSION:
        raise ValueError(f"expected version {VERSION}")
    changes = []
    for printer, state, at in data["changes"]:
        if not isinstance(printer, str) or (state is not None and state not in STATES):
            raise ValueError(f"not a state change: {[printer, state, at]!r}")
        changes.append(Change(printer, state, _time(at)))
    opened = {str(printer): _time(at) for printer, at in dict(data["opened"]).items()}
    return changes, opened


def _time(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"not a time: {value!r}")
    return float(value)
