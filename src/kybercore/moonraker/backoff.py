"""How long a session waits before reconnecting."""

from __future__ import annotations

import random
import time
from collections.abc import Callable


class Backoff:
    """Exponential backoff with jitter, capped; reset once a connection proved healthy
    (it lasted ``healthy_after`` seconds, or Moonraker ended a session that had answered).

    One exception: connections *refused* within ``restart_window`` seconds of a healthy
    session are a restart (the host answers; Moonraker is not listening yet, or the host
    is back from a reboot). Those are retried every ``refused_retry`` seconds, so the
    printer is back about a second after its Moonraker is. Timeouts and unreachable hosts,
    and a port that never answered, keep the long backoff.
    """

    def __init__(
        self,
        base: float = 0.5,
        cap: float = 30.0,
        healthy_after: float = 30.0,
        *,
        refused_retry: tuple[float, float] = (1.0, 1.5),
        restart_window: float = 300.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.base = base
        self.cap = cap
        self.healthy_after = healthy_after
        self.refused_retry = refused_retry
        self.restart_window = restart_window
        self._clock = clock
        self._attempt = 0
        self._healthy_ended: float | None = None

    def next_delay(self, connected_for: float, *, refused: bool = False) -> float:
        """Delay before the next attempt, given how long the last connection lasted and
        whether it was refused."""
        ended = self._healthy_ended
        if refused and ended is not None and self._clock() - ended < self.restart_window:
            return random.uniform(*self.refused_retry)
        if connected_for >= self.healthy_after:
            self._attempt = 0
        ceiling = min(self.cap, self.base * 2**self._attempt)
        self._attempt += 1
        # Full jitter spreads a room of printers that all dropped at once.
        return float(ceiling / 2 + random.uniform(0, ceiling / 2))

    def healthy_session_ended(self, *, by_peer: bool) -> None:
        """A connection on which Moonraker answered has ended. ``by_peer`` (Moonraker ended
        it: a restart): start again from ``base``, however many restarts came before."""
        self._healthy_ended = self._clock()
        if by_peer:
            self._attempt = 0
