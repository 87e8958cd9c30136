"""A virtual printer's webcam: JPEG snapshots and an MJPEG stream of its bed, on loopback.

Run ``python -m kybercore.sim.webcam --name printer-1 --port 8081 --moonraker
http://127.0.0.1:7125``; the printer's ``moonraker.conf`` lists it as ``[webcam kybercam]``
(see :mod:`kybercore.sim.stack`), so clients find it as they find a real camera, through
``/server/webcams/list``.

- ``GET /snapshot``: one JPEG (``Cache-Control: no-store``).
- ``GET /stream``: ``multipart/x-mixed-replace; boundary=frame``, about two frames a second,
  until the client leaves.

Standard library asyncio streams and Pillow only, no web framework: a farm demo runs dozens
of these. Idle, it does nothing: Moonraker is asked for its status (at most once a second)
and a frame is drawn (at most twice a second) only while someone is looking. SIGTERM or
SIGINT stops it, open streams included.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import signal
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, Final
from urllib.parse import quote, urlsplit

from kybercore.sim.webcam_frame import (
    CONNECTING,
    QUERY,
    CameraStatus,
    render_jpeg,
    status_from_query,
)

log = logging.getLogger("kybercore.sim.webcam")

STATUS_MAX_AGE: Final = 1.0
"""Seconds a Moonraker status is reused: the camera asks at most once a second."""
FRAME_MAX_AGE: Final = 0.4
"""Seconds a drawn frame is reused by every client (a stream asks every ``STREAM_PERIOD``)."""
STREAM_PERIOD: Final = 0.5
STATUS_WAIT: Final = 1.0
"""How long a frame waits for a fresh status before it is drawn with the last one: a frozen
Moonraker must not freeze the picture."""
MOONRAKER_TIMEOUT: Final = 10.0
_REQUEST_TIMEOUT: Final = 10.0
_MAX_HEADER_LINES: Final = 100


class MoonrakerDown(Exception):
    """Moonraker did not answer, or answered with an error (the message says which)."""


class MoonrakerPoller:
    """The printer's status from its own Moonraker, fetched at most once a second."""

    def __init__(self, base_url: str) -> None:
        parts = urlsplit(base_url)
        self._host = parts.hostname or "127.0.0.1"
        self._port = parts.port or 80
        self._status = CONNECTING
        self._fetched_at: float | None = None
        self._task: asyncio.Task[None] | None = None
        self._meta: tuple[str, Mapping[str, Any]] = ("", {})

    async def status(self) -> CameraStatus:
        """The latest status: refreshed if older than a second, waiting for it briefly."""
        fresh = (
            self._fetched_at is not None and time.monotonic() - self._fetched_at < STATUS_MAX_AGE
        )
        if not fresh:
            if self._task is None or self._task.done():
                self._task = asyncio.create_task(self._refresh())
            await asyncio.wait({self._task}, timeout=STATUS_WAIT)
        return self._status

    async def _refresh(self) -> None:
        try:
            result = await self._get(f"/printer/objects/query?{QUERY}")
            status = result.get("status", {})
            filename = str((status.get("print_stats") or {}).get("filename") or "")
            meta = await self._metadata(filename)
            self._status = status_from_query(status, meta, self._status)
        except MoonrakerDown as exc:
            # Keep the bed and the part: a camera that lost its printer still shows the plate.
            self._status = replace(self._status, state="offline", nozzle=None, message=str(exc))
        finally:
            self._fetched_at = time.monotonic()

    async def _metadata(self, filename: str) -> Mapping[str, Any]:
        """The slicer's layer heights for ``filename``, asked once per file."""
        if not filename or self._meta[0] == filename:
            return self._meta[1]
        try:
            meta = await self._get(f"/server/files/metadata?filename={quote(filename)}")
        except MoonrakerDown:
            meta = {}  # not indexed (yet): the layer shows as unknown
        self._meta = (filename, meta)
        return meta

    async def _get(self, path: str) -> dict[str, Any]:
        """``result`` of a GET on Moonraker (HTTP/1.0: one connection, never chunked)."""
        try:
            async with asyncio.timeout(MOONRAKER_TIMEOUT):
                reader, writer = await asyncio.open_connection(self._host, self._port)
                try:
                    writer.write(f"GET {path} HTTP/1.0\r\nHost: {self._host}\r\n\r\n".encode())
                    data = await reader.read()
                finally:
                    writer.close()
        except (OSError, TimeoutError):
            raise MoonrakerDown("Moonraker is not answering") from None
        head, _, body = data.partition(b"\r\n\r\n")
        try:
            code = int(head.split(b" ", 2)[1])
            answer = json.loads(body)
        except (IndexError, ValueError):
            raise MoonrakerDown("Moonraker sent an answer the camera cannot read") from None
        if code != 200 or not isinstance(answer, dict):
            message = (answer.get("error") or {}).get("message") if isinstance(answer, dict) else ""
            raise MoonrakerDown(str(message or f"Moonraker answered HTTP {code}"))
        result = answer.get("result")
        return result if isinstance(result, dict) else {}


class Camera:
    """Frames for every client, drawn at most every ``FRAME_MAX_AGE`` seconds."""

    def __init__(self, name: str, poller: MoonrakerPoller) -> None:
        self._name = name
        self._poller = poller
        self._lock = asyncio.Lock()
        self._jpeg = b""
        self._drawn_at = 0.0

    async def frame(self) -> bytes:
        """The current JPEG (clients asking together share one drawing)."""
        async with self._lock:
            if self._jpeg and time.monotonic() - self._drawn_at < FRAME_MAX_AGE:
                return self._jpeg
            status = await self._poller.status()
            clock = time.strftime("%H:%M:%S")
            # Drawing and encoding take milliseconds: off the loop, so streams keep flowing.
            self._jpeg = await asyncio.to_thread(render_jpeg, self._name, status, clock)
            self._drawn_at = time.monotonic()
            return self._jpeg


class WebcamServer:
    """The HTTP side: /snapshot and /stream on 127.0.0.1."""

    def __init__(self, camera: Camera) -> None:
        self._camera = camera
        self._clients: set[asyncio.Task[Any]] = set()

    async def serve(self, port: int, stop: asyncio.Event) -> None:
        """Listen on ``127.0.0.1:port`` until ``stop`` is set, then end every client."""
        server = await asyncio.start_server(self._handle, "127.0.0.1", port)
        log.info("webcam listening on 127.0.0.1:%d", port)
        async with server:
            await stop.wait()
            server.close()
            for task in list(self._clients):
                task.cancel()
            await asyncio.gather(*self._clients, return_exceptions=True)

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._clients.add(task)
        try:
            target = await self._read_request(reader)
            if target is None:
                await _respond(writer, "405 Method Not Allowed", "text/plain", b"GET only\n")
            elif target == "/snapshot":
                await _respond(writer, "200 OK", "image/jpeg", await self._camera.frame())
            elif target == "/stream":
                await self._stream(reader, writer)
            else:
                body = b"This camera serves /snapshot (JPEG) and /stream (MJPEG).\n"
                await _respond(writer, "404 Not Found", "text/plain", body)
        except (OSError, TimeoutError, ValueError):
            pass  # the client left or sent something that is not HTTP: nothing to answer
        finally:
            self._clients.discard(task)
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()

    @staticmethod
    async def _read_request(reader: asyncio.StreamReader) -> str | None:
        """The request's path (its query ignored), or None when the method is not GET."""
        async with asyncio.timeout(_REQUEST_TIMEOUT):
            method, target, _version = (await reader.readline()).decode("latin-1").split()
            for _ in range(_MAX_HEADER_LINES):
                if (await reader.readline()).strip() == b"":
                    break
        return target.split("?", 1)[0] if method == "GET" else None

    async def _stream(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(
            b"HTTP/1.1 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=frame\r\n"
            b"Cache-Control: no-store\r\nConnection: close\r\n\r\n"
        )
        # The client sends nothing more: end of its input means it left.
        gone = asyncio.create_task(_until_eof(reader))
        try:
            while not gone.done():
                jpeg = await self._camera.frame()
                writer.write(
                    b"--frame\r\nContent-Type: image/jpeg\r\n"
                    + f"Content-Length: {len(jpeg)}\r\n\r\n".encode()
                    + jpeg
                    + b"\r\n"
                )
                await writer.drain()
                await asyncio.wait({gone}, timeout=STREAM_PERIOD)
        finally:
            gone.cancel()


async def _until_eof(reader: asyncio.StreamReader) -> None:
    while await reader.read(1024):
        pass


async def _respond(writer: asyncio.StreamWriter, status: str, kind: str, body: bytes) -> None:
    writer.write(
        f"HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {len(body)}\r\n"
        "Cache-Control: no-store\r\nConnection: close\r\n\r\n".encode()
        + body
    )
    await writer.drain()


async def run(name: str, port: int, moonraker_url: str) -> None:
    """Serve the camera until SIGTERM or SIGINT."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, stop.set)
    server = WebcamServer(Camera(name, MoonrakerPoller(moonraker_url)))
    await server.serve(port, stop)
    log.info("webcam stopped")


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    parser = argparse.ArgumentParser(
        prog="python -m kybercore.sim.webcam",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--name", required=True, help="The printer's name, drawn on every frame.")
    parser.add_argument("--port", type=int, required=True, help="Port on 127.0.0.1.")
    parser.add_argument("--moonraker", required=True, help="The printer's Moonraker URL.")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the process exit code (1 when the port cannot be had)."""
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    try:
        asyncio.run(run(args.name, args.port, args.moonraker))
    except OSError as exc:
        log.error("cannot listen on 127.0.0.1:%d: %s", args.port, exc.strerror)  # noqa: TRY400
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
