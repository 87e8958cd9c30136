"""FAULT-INJECTION stand-in — not a network: a loopback TCP relay standing for a WAN link a
test cuts and mends (a site's NATS leaf node to its hub, a site's worker to the central
PostgreSQL). Both ends are real servers; they cannot be parted on demand without stopping
one of them, and a stopped server is another failure."""

from __future__ import annotations

import asyncio
import contextlib
import threading

from sqlalchemy.engine import make_url

from kybercore.sim.stack import free_port


class Cable:
    """Relays TCP from :attr:`port` to ``upstream_port`` on loopback, on a thread of its own
    (the tests driving it are synchronous)."""

    def __init__(self, upstream_port: int) -> None:
        self.port = free_port()
        self._upstream = upstream_port
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="cable", daemon=True)
        self._server: asyncio.Server | None = None
        self._ends: set[asyncio.StreamWriter] = set()

    def start(self) -> None:
        """Start relaying."""
        self._thread.start()
        self.mend()

    def cut(self) -> None:
        """Drop every connection through it and refuse new ones, as a cut line would."""
        asyncio.run_coroutine_threadsafe(self._cut(), self._loop).result(10)

    def mend(self) -> None:
        """Take connections again (the clients reconnect by themselves)."""
        asyncio.run_coroutine_threadsafe(self._listen(), self._loop).result(10)

    def close(self) -> None:
        """Cut it and stop its thread."""
        self.cut()
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()

    async def _listen(self) -> None:
        self._server = await asyncio.start_server(self._relay, "127.0.0.1", self.port)

    async def _cut(self) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None
        for end in list(self._ends):
            end.transport.abort()

    async def _relay(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self._upstream)
        except OSError:
            writer.transport.abort()
            return
        ends = {writer, up_writer}
        self._ends |= ends
        try:
            await asyncio.gather(_pipe(reader, up_writer), _pipe(up_reader, writer))
        finally:
            self._ends -= ends


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    """Copy until either side ends, then end the other."""
    with contextlib.suppress(OSError):
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    writer.transport.abort()


def to_database(database_url: str) -> tuple[Cable, str]:
    """A started cable to the database at ``database_url``, and the URL by way of it."""
    url = make_url(database_url)
    assert url.port is not None
    cable = Cable(url.port)
    cable.start()
    return cable, url.set(port=cable.port).render_as_string(hide_password=False)
