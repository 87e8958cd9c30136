"""How long a session waits before reconnecting."""

from __future__ import annotations

import random


class Backoff:
    """Exponential backoff with jitter, capped; reset once a connection proved healthy
    (it lasted ``healthy_after`` seconds, or the session called :meth:`reset`)."""

    def __init__(self, base: float = 0.5, cap: float = 30.0, healthy_after: float = 30.0) -> None:
        self.base = base
        self.cap = cap
        self.healthy_after = healthy_after
        self._attempt = 0

    def next_delay(self, connected_for: float) -> float:
        """Delay before the next attempt, given how long the last connection lasted."""
        if connected_for >= self.healthy_after:
            self._attempt = 0
        ceiling = min(self.cap, self.base * 2**self._attempt)
        self._attempt += 1
        # Full jitter spreads a room of printers that all dropped at once.
        return float(ceiling / 2 + random.uniform(0, ceiling / 2))

    def reset(self) -> None:
        """Start again from ``base``: the peer answered, so the next drop is news."""
        self._attempt = 0
