"""A printer's connection and Klippy state changes, one INFO line each, rate-limited.

An operator reading the log the morning after should see the night's outages and
recoveries, named by printer and reason; a printer that flaps must not flood it. So each
printer logs at most one line per state per ``every`` seconds, and the next line of that
state says how many it stands for.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Final

log = logging.getLogger(__name__)

LOG_EVERY: Final = 60.0


class StateLog:
    """The log of one printer's state changes."""

    def __init__(
        self, printer: str, every: float = LOG_EVERY, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._printer = printer
        self._every = every
        self._clock = clock
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def connection(self, state: str, reason: str = "") -> None:
        """Moonraker's connection is now ``state`` (online, offline, auth_failed)."""
        self._line(f"Moonraker {state}", reason)

    def klippy(self, state: str, before: str, reason: str = "") -> None:
        """Klippy went from ``before`` to ``state``."""
        self._line(f"Klippy {state}", reason, f" (was {before})")

    def _line(self, key: str, reason: str, context: str = "") -> None:
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self._every:
            self._held[key] = self._held.get(key, 0) + 1
            return
        self._last[key] = now
        held = self._held.pop(key, 0)
        more = f" (and {held} more times in the last {self._every:g} s)" if held else ""
        because = f": {reason}" if reason else ""
        log.info("%s: %s%s%s%s", self._printer, key, context, because, more)
