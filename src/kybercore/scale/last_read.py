"""The printers a worker last read from the registry, kept on its own disk to start on when
the registry cannot be read.

The registry lives in the hub's JetStream. A site's worker restarted while its site is cut
off from the hub (a reboot, an update) would otherwise stop at start with the broker's
error, leaving the site's printers unheld although the site's own leaf node, its leases
(``--local-leases``) and its printers are all there. With this copy it holds them again,
and follows the registry once the hub answers.
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Final

from kybercore.errors import ConfigError
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import read_printers, write_printers

log = logging.getLogger(__name__)

FILE: Final = "last-registry.json"
"""In the worker's folder (``--dir``); a printers.json of its site's printers, API keys
included, so written 0600 like printers.json."""


class LastRead:
    """The newest list of printers read, written in the background (:meth:`run`)."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / FILE
        self._newest: list[PrinterConfig] = []
        self._changed = asyncio.Event()

    def keep(self, printers: list[PrinterConfig]) -> None:
        """Note ``printers`` as the newest read; :meth:`run` writes it."""
        self._newest = printers
        self._changed.set()

    async def run(self) -> None:
        """Write the newest list after each change, off the event loop (run it as a task).
        Changes noted while a write runs make one more write, of the newest."""
        while True:
            await self._changed.wait()
            self._changed.clear()
            try:
                await asyncio.to_thread(write_printers, self.path, self._newest)
            except OSError as exc:
                log.warning(
                    "%s: cannot keep the printers read from the registry (%s); if this worker "
                    "restarts while the registry cannot be read, it will have none to start on",
                    self.path, exc,
                )  # fmt: skip

    async def written(self) -> bool:
        """Whether a list was ever written (this worker ran before)."""
        return await asyncio.to_thread(self.path.exists)

    async def load(self) -> list[PrinterConfig] | None:
        """The printers written last; None when there are none (never written, or spoiled:
        said in the log)."""

        def read() -> list[PrinterConfig] | None:
            return read_printers(self.path) if self.path.exists() else None

        try:
            return await asyncio.to_thread(read)
        except ConfigError as exc:
            log.warning("cannot start on the printers read last: %s", exc.message)
            return None
