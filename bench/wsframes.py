"""Just enough of RFC 6455 for the load generator and the draining browsers: pure, no I/O.

The load generator writes ~20,000 frames/s at N = 5,000, more than a general-purpose
WebSocket server spares on a 2-core machine next to the process being measured. Server
frames are unmasked, so a frame is a 2-10 byte header plus the payload. Client frames
(KyberCore's JSON-RPC requests, pings, close) are small, masked and unfragmented. The
draining browsers (:mod:`bench.drain`) only need to find frame boundaries and answer pings.
"""

from __future__ import annotations

import base64
import hashlib
import struct
from dataclasses import dataclass
from typing import Final

TEXT: Final = 0x1
CLOSE: Final = 0x8
PING: Final = 0x9
PONG: Final = 0xA
_GUID: Final = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"


def accept_key(client_key: str) -> str:
    """``Sec-WebSocket-Accept`` for a client's ``Sec-WebSocket-Key``."""
    digest = hashlib.sha1(client_key.encode() + _GUID).digest()  # RFC 6455 names SHA-1
    return base64.b64encode(digest).decode()


def encode(payload: bytes, opcode: int = TEXT, mask: bytes | None = None) -> bytes:
    """One final frame: unmasked (server), or masked with a 4-byte ``mask`` (client)."""
    size = len(payload)
    first = 0x80 | opcode
    masked = 0x80 if mask is not None else 0
    if size < 126:
        header = struct.pack("!BB", first, masked | size)
    elif size < 65536:
        header = struct.pack("!BBH", first, masked | 126, size)
    else:
        header = struct.pack("!BBQ", first, masked | 127, size)
    if mask is None:
        return header + payload
    return header + mask + _unmask(payload, mask)


def bounds(buffer: bytearray) -> tuple[int, int, int] | None:
    """(opcode, payload start, frame end) of the frame at the front of ``buffer``, without
    copying it; None until the header is all there. The payload may still be arriving."""
    if len(buffer) < 2:
        return None
    size = buffer[1] & 0x7F
    offset = 2
    if size == 126:
        if len(buffer) < 4:
            return None
        (size,) = struct.unpack_from("!H", buffer, 2)
        offset = 4
    elif size == 127:
        if len(buffer) < 10:
            return None
        (size,) = struct.unpack_from("!Q", buffer, 2)
        offset = 10
    if buffer[1] & 0x80:
        offset += 4  # the mask key
    return buffer[0] & 0x0F, offset, offset + size


@dataclass(frozen=True, slots=True)
class Frame:
    """A client frame, unmasked."""

    opcode: int
    payload: bytes


def decode(buffer: bytearray) -> Frame | None:
    """Take one complete frame off the front of ``buffer``; None if it is not all there."""
    found = bounds(buffer)
    if found is None or len(buffer) < found[2]:
        return None
    opcode, start, end = found
    payload = bytes(buffer[start:end])
    if buffer[1] & 0x80:
        payload = _unmask(payload, bytes(buffer[start - 4 : start]))
    del buffer[:end]
    return Frame(opcode, payload)


def _unmask(payload: bytes, mask: bytes) -> bytes:
    # XOR as one big integer: fast enough for the small frames clients send.
    repeated = (mask * (len(payload) // 4 + 1))[: len(payload)]
    value = int.from_bytes(payload, "big") ^ int.from_bytes(repeated, "big")
    return value.to_bytes(len(payload), "big")
