"""A browser that reads every byte KyberCore sends on ``/ws`` and parses only frame headers.

100 dashboards at N = 5,000 receive ~400 MB/s between them. A ``websockets`` client per
dashboard would spend more CPU in this benchmark's process than KyberCore spends sending,
so all but the measuring clients are this: a raw :class:`asyncio.Protocol` that does the
handshake, answers pings (uvicorn closes a client that does not), notes snapshots
(KyberCore resends one when a client's queue overflowed) and drops the rest unread.

Given a view (the printer ids it shows), it sends ``{"type": "view", "printers": [...]}``
right after its snapshot, as a masked text frame (RFC 6455: every client frame is masked;
KyberCore reads the message as text), and is ready once a delta carries the ``full`` part
that only a client with a view gets: until then it still receives the whole fleet in full.

With ``deflate``, it offers permessage-deflate (RFC 7692) as Chromium does, and inflates
what arrives compressed: the server then compresses every frame for this client alone.
"""

from __future__ import annotations

import asyncio
import base64
import os
import zlib
from typing import Final

import orjson

from bench import wsframes

SNAPSHOT: Final = b'{"type":"snapshot"'
DELTA: Final = b'{"type":"delta"'
# The full patches of the printers in a client's view follow the slim summaries of the
# fleet's (see kybercore.fleet.frames.DeltaFrames.frame); no view key is named "full".
FULL: Final = b',"full":'
OFFER: Final = "Sec-WebSocket-Extensions: permessage-deflate; client_max_window_bits\r\n"
TAIL: Final = b"\x00\x00\xff\xff"
"""What a compressed message's sender strips and its reader puts back (RFC 7692 7.2.2)."""


class DrainClient(asyncio.Protocol):
    """One draining browser on ``ws://host:port/ws``."""

    def __init__(
        self,
        host: str,
        port: int,
        ready: asyncio.Future[None],
        view: list[str] | None = None,
        deflate: bool = False,
    ) -> None:
        self._request = (
            f"GET /ws HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            "Connection: Upgrade\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: "
            f"{base64.b64encode(os.urandom(16)).decode()}\r\n{OFFER if deflate else ''}\r\n"
        ).encode()
        self._inflate: zlib._Decompress | None = None
        self._takeover = True
        """Whether the server keeps its compression context from one message to the next."""
        self._ready = ready
        self._view = None if view is None else orjson.dumps({"type": "view", "printers": view})
        self._view_sent = False
        self._buffer = bytearray()
        self._open = False
        self._transport: asyncio.Transport | None = None
        self.frames = 0
        self.bytes = 0
        self.snapshots = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport
        transport.write(self._request)

    def connection_lost(self, exc: Exception | None) -> None:
        if not self._ready.done():
            self._ready.set_exception(ConnectionError(f"/ws closed before its snapshot: {exc}"))

    def data_received(self, data: bytes) -> None:
        self._buffer += data
        if not self._open:
            end = self._buffer.find(b"\r\n\r\n")
            if end < 0:
                return
            if not self._buffer.startswith(b"HTTP/1.1 101"):
                raise ConnectionError(bytes(self._buffer[:end]).decode("latin-1"))
            headers = bytes(self._buffer[:end]).lower()
            if b"permessage-deflate" in headers:
                self._inflate = zlib.decompressobj(wbits=-15)
                self._takeover = b"server_no_context_takeover" not in headers
            del self._buffer[: end + 4]
            self._open = True
        while (found := wsframes.bounds(self._buffer)) is not None:
            opcode, start, end = found
            if len(self._buffer) < end:
                return  # the payload is still arriving
            self._frame(opcode, start, end)
            del self._buffer[:end]

    def _frame(self, opcode: int, start: int, end: int) -> None:
        if opcode == wsframes.PING and self._transport is not None:
            payload = bytes(self._buffer[start:end])
            self._transport.write(wsframes.encode(payload, wsframes.PONG, os.urandom(4)))
            return
        self.frames += 1
        self.bytes += end - start
        if self._inflate is not None and self._buffer[0] & 0x40:  # RSV1: compressed
            self._inflated(bytes(self._buffer[start:end]))
        else:
            self._message(self._buffer, start, end)

    def _inflated(self, payload: bytes) -> None:
        assert self._inflate is not None
        message = self._inflate.decompress(payload + TAIL)
        if not self._takeover:
            self._inflate = zlib.decompressobj(wbits=-15)
        self._message(message, 0, len(message))

    def _message(self, data: bytes | bytearray, start: int, end: int) -> None:
        """A data frame's payload, ``data[start:end]``, uncompressed."""
        if data.startswith(SNAPSHOT, start):
            self.snapshots += 1
            if self._view is None:
                if not self._ready.done():
                    self._ready.set_result(None)
            elif not self._view_sent and self._transport is not None:
                self._transport.write(wsframes.encode(self._view, wsframes.TEXT, os.urandom(4)))
                self._view_sent = True
        elif (
            self._view_sent
            and not self._ready.done()
            and data.startswith(DELTA, start)
            # Searched only until the view is in effect: one frame, not the window's.
            and data.find(FULL, start, end) >= 0
        ):
            self._ready.set_result(None)

    def close(self) -> None:
        """Drop the connection."""
        if self._transport is not None:
            self._transport.close()
