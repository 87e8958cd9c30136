"""A webcam snapshot to attach to a notification, from the printer's own webcam list.

Moonraker lists the webcams configured in ``moonraker.conf`` (``[webcam name]``) or added
from a frontend at ``/server/webcams/list``. Their ``snapshot_url`` is often relative
(``/webcam/?action=snapshot``, served by the frontend's web server on the printer's host):
it is resolved against the printer's URL. Only a JPEG is taken, and only a small one; a
snapshot is a nicety, so any failure is ``None``, never an error.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Final
from urllib.parse import urlsplit, urlunsplit

import httpx

from kybercore.moonraker.client import MoonrakerClient

log = logging.getLogger(__name__)

MAX_SNAPSHOT: Final = 5 * 1024 * 1024
"""Bytes: a webcam's JPEG is tens or hundreds of kB; more is not a snapshot."""
JPEG_MAGIC: Final = b"\xff\xd8\xff"
_HTTP: Final = ("http", "https")


def resolve_snapshot_url(printer_url: str, snapshot_url: str) -> str | None:
    """``snapshot_url`` as an absolute http(s) URL, or None when it is empty or of another
    kind (``rtsp://``, ``file:``…).

    A relative one (``/webcam/?action=snapshot``, ``webcam/snap``) is taken from the root of
    the printer's scheme, host and port; ``//host/path`` gets the printer's scheme.
    """
    candidates = snapshot_candidates(printer_url, snapshot_url)
    return candidates[0] if candidates else None


def snapshot_candidates(printer_url: str, snapshot_url: str) -> list[str]:
    """Where the snapshot may be, best guess first.

    A relative URL is the frontend's web server's: on the printer's own port when its URL
    is the frontend's (``http://voron.local``), and, as Moonraker reads it, on the host's
    default port when the URL is Moonraker's own (``http://voron.local:7125``). Both are
    tried, in that order.
    """
    wanted = snapshot_url.strip()
    printer = urlsplit(printer_url.strip())
    if not wanted or printer.scheme not in _HTTP or not printer.hostname:
        return []
    if wanted.startswith("//"):
        wanted = f"{printer.scheme}:{wanted}"
    target = urlsplit(wanted)
    if target.scheme:
        return [wanted] if target.scheme in _HTTP and target.hostname else []
    path = "/" + target.path.lstrip("/")
    first = urlunsplit((printer.scheme, printer.netloc, path, target.query, ""))
    if printer.port is None:
        return [first]
    host = printer.hostname if ":" not in printer.hostname else f"[{printer.hostname}]"
    return [first, urlunsplit((printer.scheme, host, path, target.query, ""))]


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
    for webcam in await client.webcams_list():
        if not webcam.get("enabled", True):
            continue
        for url in snapshot_candidates(printer_url, str(webcam.get("snapshot_url") or "")):
            image = await _fetch_jpeg(http, url)
            if image is not None:
                return image
    return None


async def _fetch_jpeg(http: httpx.AsyncClient, url: str) -> bytes | None:
    try:
        async with http.stream("GET", url, follow_redirects=True) as answer:
            if not answer.is_success:
                return None
            declared = answer.headers.get("content-length", "")
            if declared.isdigit() and int(declared) > MAX_SNAPSHOT:
                return None
            image = bytearray()
            async for chunk in answer.aiter_bytes():
                image += chunk
                # Checked early: a stream (multipart MJPEG) or a page is never read whole.
                if len(image) >= len(JPEG_MAGIC) and not image.startswith(JPEG_MAGIC):
                    return None
                if len(image) > MAX_SNAPSHOT:
                    return None
    except httpx.HTTPError as exc:
        log.debug("snapshot %s: %s", url, exc)
        return None
    return bytes(image) if image.startswith(JPEG_MAGIC) else None
