"""A bare HTTP/1.1 keep-alive client for the fleet-view latency poll.

httpx parses responses in Python: on an idle KyberCore serving 1,000 printers, the same
``GET /api/printers`` (1 MB) took 4.2 ms with httpx and 1.8 ms over a plain socket. The
fleet-view latency should measure KyberCore, not the measuring client, so the poll reads
the answer with asyncio streams: status line, headers, then exactly Content-Length bytes.
"""

from __future__ import annotations

import asyncio


class ReadFailed(Exception):
    """The request got no complete 200 answer."""


class FleetReader:
    """One keep-alive connection to ``host:port``, reopened after a failure."""

    def __init__(self, host: str, port: int, timeout: float) -> None:
        self.host = host
        self.port = port
        self.timeout = timeout
        self._streams: tuple[asyncio.StreamReader, asyncio.StreamWriter] | None = None

    async def get(self, path: str) -> bytes:
        """The body of ``GET path``; :class:`ReadFailed` unless it is a complete 200."""
        try:
            return await asyncio.wait_for(self._get(path), self.timeout)
        except (OSError, TimeoutError, asyncio.IncompleteReadError, KeyError, ValueError) as exc:
            await self.close()
            raise ReadFailed(f"GET {path}: {exc!r}") from exc

    async def _get(self, path: str) -> bytes:
        if self._streams is None:
            self._streams = await asyncio.open_connection(self.host, self.port, limit=2**20)
        reader, writer = self._streams
        writer.write(f"GET {path} HTTP/1.1\r\nHost: {self.host}:{self.port}\r\n\r\n".encode())
        head = await reader.readuntil(b"\r\n\r\n")
        status_line, *header_lines = head.decode("latin-1").split("\r\n")
        if status_line.split(" ")[1] != "200":
            raise ValueError(status_line)
        headers = dict(line.split(":", 1) for line in header_lines if ":" in line)
        length = int({k.lower(): v for k, v in headers.items()}["content-length"])
        return await reader.readexactly(length)

    async def close(self) -> None:
        """Close the connection (the next :meth:`get` opens a new one)."""
        streams, self._streams = self._streams, None
        if streams is not None:
            streams[1].close()
            await asyncio.gather(streams[1].wait_closed(), return_exceptions=True)
