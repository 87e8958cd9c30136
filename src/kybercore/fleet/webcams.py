"""Printers' webcams as Moonraker lists them (``/server/webcams/list``), for the camera
wall, the printer page and notification snapshots.

Moonraker lists the webcams configured in ``moonraker.conf`` (``[webcam name]``) or added
from a frontend. Their URLs are often relative (``/webcam/?action=snapshot``, served by the
frontend's web server on the printer's host): they are resolved against the printer's URL.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass
from typing import Any, Final, Protocol
from urllib.parse import urlsplit, urlunsplit

import httpx

from kybercore.aio import Remembered
from kybercore.errors import ActionRejected, FileNotFound, PrinterUnreachable, shorten
from kybercore.moonraker.client import MoonrakerClient

log = logging.getLogger(__name__)

MAX_SNAPSHOT: Final = 5 * 1024 * 1024
"""Bytes: a webcam's JPEG is tens or hundreds of kB; more is not a snapshot."""
JPEG_MAGIC: Final = b"\xff\xd8\xff"
_HTTP: Final = ("http", "https")
_LIST_SECONDS: Final = 5.0
"""How long a printer's webcam list is reused (a webcam added shows within this)."""
# A stream sends a frame every second or so; a camera silent for 30 s is gone.
_STREAM_TIMEOUT: Final = httpx.Timeout(10.0, read=30.0)


@dataclass(frozen=True, slots=True)
class Webcam:
    """One webcam of a printer, its URLs resolved (best guess first)."""

    name: str
    enabled: bool
    snapshot_urls: list[str]
    stream_urls: list[str]
    flip_horizontal: bool
    flip_vertical: bool
    rotation: int
    aspect_ratio: str


def camera_candidates(printer_url: str, camera_url: str) -> list[str]:
    """Where a webcam's snapshot or stream may be, best guess first.

    A relative URL is the frontend's web server's: on the printer's own port when its URL
    is the frontend's (``http://voron.local``), and, as Moonraker reads it, on the host's
    default port when the URL is Moonraker's own (``http://voron.local:7125``). Both are
    tried, in that order. ``//host/path`` gets the printer's scheme; other schemes
    (``rtsp://``, ``file:``) give nothing.
    """
    wanted = camera_url.strip()
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


def webcams_of(printer_url: str, listed: list[dict[str, Any]]) -> list[Webcam]:
    """Moonraker's webcam list, read defensively (fields are whatever the peer sent)."""
    cams = []
    for entry in listed:
        name = entry.get("name")
        if not isinstance(name, str) or not name:
            continue
        rotation = entry.get("rotation")
        cams.append(
            Webcam(
                name=name,
                enabled=entry.get("enabled", True) is not False,
                snapshot_urls=camera_candidates(printer_url, _text(entry, "snapshot_url")),
                stream_urls=camera_candidates(printer_url, _text(entry, "stream_url")),
                flip_horizontal=entry.get("flip_horizontal") is True,
                flip_vertical=entry.get("flip_vertical") is True,
                rotation=rotation if rotation in (0, 90, 180, 270) else 0,
                aspect_ratio=_text(entry, "aspect_ratio") or "4:3",
            )
        )
    return cams


def _text(entry: Mapping[str, Any], key: str) -> str:
    value = entry.get(key)
    return value if isinstance(value, str) else ""


async def first_jpeg(http: httpx.AsyncClient, urls: list[str]) -> bytes | None:
    """The first of ``urls`` that gives a JPEG of at most :data:`MAX_SNAPSHOT` bytes."""
    for url in urls:
        image = await fetch_jpeg(http, url)
        if image is not None:
            return image
    return None


async def fetch_jpeg(http: httpx.AsyncClient, url: str) -> bytes | None:
    """One JPEG from ``url``, or None (not a JPEG, too big, an error answer, unreachable)."""
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


class WebcamProxy:
    """Webcams reached through KyberCore: browsers need no route to the printers' network,
    and KyberCore's access rules apply. At most ``max_streams`` live streams per printer
    (each holds a connection to a camera that serves few)."""

    def __init__(self, http: httpx.AsyncClient, max_streams: int = 4) -> None:
        self._http = http
        self._max_streams = max_streams
        self._streams: dict[str, int] = {}
        # The camera wall asks for a snapshot every few hundred ms: the list each one needs
        # comes from Moonraker at most every few seconds, not once per picture.
        self._lists: Remembered[str, list[dict[str, Any]]] = Remembered(_LIST_SECONDS)

    async def cameras(self, client: MoonrakerClient, printer_url: str) -> list[Webcam]:
        """The printer's enabled webcams (Moonraker's list, a few seconds old at most)."""
        listed = await self._lists.get(printer_url, client.webcams_list)
        return [c for c in webcams_of(printer_url, listed) if c.enabled]

    async def camera(
        self, client: MoonrakerClient, printer_url: str, printer_id: str, name: str
    ) -> Webcam:
        """The enabled webcam called ``name``; :class:`FileNotFound` when there is none."""
        for cam in await self.cameras(client, printer_url):
            if cam.name == name:
                return cam
        raise FileNotFound(
            f"{printer_id} has no webcam '{shorten(name)}'. "
            f"GET /api/printers/{printer_id}/webcams lists its webcams."
        )

    async def snapshot(self, cam: Webcam, printer_id: str) -> bytes:
        """One JPEG from the webcam; :class:`PrinterUnreachable` when it gives none."""
        image = await first_jpeg(self._http, cam.snapshot_urls)
        if image is None:
            raise PrinterUnreachable(
                f"webcam '{cam.name}' gave no JPEG snapshot "
                f"(tried {', '.join(cam.snapshot_urls) or 'no usable URL'}). "
                "Check the camera and its snapshot_url in moonraker.conf.",
                printer=printer_id,
            )
        return image

    async def stream(self, cam: Webcam, printer_id: str) -> CameraStream:
        """The webcam's MJPEG stream, relayed as it comes; it counts against the printer's
        limit until closed."""
        if self._streams.get(printer_id, 0) >= self._max_streams:
            raise ActionRejected(
                f"{printer_id}: {self._max_streams} webcam streams are open already; close "
                "one (another tab or browser) or use the snapshots of the camera wall.",
                code="too_many_streams",
            )
        for url in cam.stream_urls:
            request = self._http.build_request("GET", url, timeout=_STREAM_TIMEOUT)
            try:
                answer = await self._http.send(request, stream=True)
            except httpx.HTTPError as exc:
                log.debug("stream %s: %s", url, exc)
                continue
            kind = answer.headers.get("content-type", "")
            if answer.is_success and kind.startswith("multipart/"):
                return _Relayed(kind, answer, self._streams, printer_id)
            await answer.aclose()
        raise PrinterUnreachable(
            f"webcam '{cam.name}' gave no MJPEG stream "
            f"(tried {', '.join(cam.stream_urls) or 'no usable URL'}). "
            "Check the camera and its stream_url in moonraker.conf.",
            printer=printer_id,
        )


class CameraStream(Protocol):
    """A live MJPEG stream being relayed: its content type, its bytes as they come, and
    :meth:`aclose`, which whoever opened it must call however it ends (also when it was
    never read: a browser may leave before the first byte), and may call twice."""

    content_type: str

    def __aiter__(self) -> AsyncIterator[bytes]: ...

    async def aclose(self) -> None:
        """Let go of the camera's connection (or of whatever carries the stream)."""


class _Relayed:
    """A camera's stream read straight from the camera (``kybercore serve``, a worker)."""

    def __init__(
        self, kind: str, answer: httpx.Response, counts: dict[str, int], printer_id: str
    ) -> None:
        self.content_type = kind
        self._answer = answer
        self._counts = counts
        self._printer_id = printer_id
        counts[printer_id] = counts.get(printer_id, 0) + 1
        self._open = True

    def __aiter__(self) -> AsyncIterator[bytes]:
        return self._answer.aiter_raw()

    async def aclose(self) -> None:
        """Close the camera's connection; the printer has one stream fewer open."""
        if self._open:
            self._open = False
            self._counts[self._printer_id] -= 1
            await self._answer.aclose()
