"""A webcam snapshot to attach to a notification, from the printer's own webcam list
(:mod:`kybercore.fleet.webcams`). A snapshot is a nicety, so any failure is ``None``, never
an error.
"""

from __future__ import annotations

import asyncio
import logging

import httpx

from kybercore.fleet.webcams import first_jpeg, webcams_of
from kybercore.moonraker.client import MoonrakerClient

log = logging.getLogger(__name__)


async def take_snapshot(
    client: MoonrakerClient, printer_url: str, http: httpx.AsyncClient, timeout: float = 5.0
) -> bytes | None:
    """A JPEG from the printer's first enabled webcam that gives one, or None (no webcam,
    not a JPEG, too big, unreachable, slower than ``timeout`` seconds in all). Never
    raises."""
    try:
        async with asyncio.timeout(timeout):
            return await _first_snapshot(client, printer_url, http)
    except Exception as exc:  # a snapshot is optional: whatever went wrong, send without
        log.debug("%s: no snapshot (%s: %s)", client.name, type(exc).__name__, exc)
        return None


async def _first_snapshot(
    client: MoonrakerClient, printer_url: str, http: httpx.AsyncClient
) -> bytes | None:
    for webcam in webcams_of(printer_url, await client.webcams_list()):
        if webcam.enabled:
            image = await first_jpeg(http, webcam.snapshot_urls)
            if image is not None:
                return image
    return None
