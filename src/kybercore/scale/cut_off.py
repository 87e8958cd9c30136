"""A front cut off from the NATS broker, said once for the whole fleet.

Every tile going stale at once reads as every printer failing, when it is the front that
cannot hear them: browsers get one ``broker`` event when the front loses the broker and one
when it has it back, and a browser connecting meanwhile gets it after its snapshot.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, Final

STALE_MESSAGE: Final = (
    "This KyberCore front has lost its connection to the NATS broker: the last state it "
    "received is shown, and updates come again once the broker is back. The printer itself "
    "may be fine."
)
"""Each printer's ``connection_error`` while its front is cut off."""

log = logging.getLogger(__name__)


class CutOff:
    """Whether the front is cut off, since when, and telling browsers when that changes."""

    def __init__(self, tell: Callable[[dict[str, Any]], None]) -> None:
        """``tell``: sends an event frame to every browser (the hub's)."""
        self._tell = tell
        self.since: float | None = None
        """time() when the front noticed it lost the broker; None while connected."""

    def follow(self, connected: bool) -> None:
        """Note whether the front is connected now; tell the browsers of a change."""
        if connected == (self.since is None):
            return
        self.since = None if connected else time.time()
        log.warning("front: %s the NATS broker", "back on" if connected else "cut off from")
        self._tell(self.frame() or {"type": "broker", "connected": True})

    def frame(self) -> dict[str, Any] | None:
        """``{"type": "broker", "connected": false, "since": time()}`` while cut off."""
        if self.since is None:
            return None
        return {"type": "broker", "connected": False, "since": self.since}
