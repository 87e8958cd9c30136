"""The WebSocket link to one Moonraker, over picows: open, messages to a callback, ping, close.

Frames are decoded and handed on inside picows' ``on_ws_frame`` callback, on the event
loop's read path. At thousands of printers x 4 status updates/s, a task wake-up per message
(what an ``async for`` client costs) would be most of the process' CPU.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable, Mapping, MutableMapping
from typing import Any, Final

import orjson
from picows import (
    WSAutoPingStrategy,
    WSCloseCode,
    WSFrame,
    WSListener,
    WSMsgType,
    WSProtocolError,
    WSTransport,
)

log = logging.getLogger(__name__)

Connect = Callable[..., Awaitable[tuple[WSTransport, WSListener]]]
"""Opens the WebSocket: :func:`picows.ws_connect`, or a wrapper with its signature
(injectable; extra keywords such as ``local_addr`` reach ``loop.create_connection``)."""

MessageCallback = Callable[[dict[str, Any]], None]

_DATA: Final = (WSMsgType.TEXT, WSMsgType.BINARY)


class LinkLost(Exception):
    """The socket is gone. ``by_peer``: Moonraker ended it (a restart, a dropped TCP link),
    as opposed to a fault KyberCore found (a frame too big, pongs that never came)."""

    def __init__(self, why: str, *, by_peer: bool) -> None:
        super().__init__(why)
        self.why = why
        self.by_peer = by_peer


class _PicowsLog(logging.LoggerAdapter):  # type: ignore[type-arg]
    """picows logs the upgrade request, the API key among its headers, and raw data below
    DEBUG, and a line per connect and disconnect at INFO: pass warnings and errors only,
    each named by its printer."""

    def __init__(self, printer: str) -> None:
        super().__init__(log)
        self.printer = printer

    def isEnabledFor(self, level: int) -> bool:
        return level >= logging.WARNING and self.logger.isEnabledFor(level)

    def process(self, msg: Any, kwargs: MutableMapping[str, Any]) -> tuple[Any, Any]:
        return f"{self.printer}: {msg}", kwargs


async def open_link(
    url: str,
    *,
    name: str,
    on_message: MessageCallback,
    headers: Mapping[str, str],
    connect: Connect,
    open_timeout: float,
    ping_interval: float,
    ping_timeout: float,
    max_bytes: int,
) -> MoonrakerLink:
    """Connect and upgrade within ``open_timeout`` s, then keep the peer under watch: after
    ``ping_interval`` s without a byte, a ping that gets no pong in ``ping_timeout`` s
    closes the link. A frame (or message) over ``max_bytes`` closes it too."""
    link = MoonrakerLink(name, on_message, ping_timeout, max_bytes)
    try:
        async with asyncio.timeout(open_timeout):
            await connect(
                lambda: link,
                url,
                extra_headers=dict(headers),
                logger_name=_PicowsLog(name),
                # picows closes a stalled handshake itself, even once we stopped waiting.
                websocket_handshake_timeout=open_timeout,
                enable_auto_ping=True,
                auto_ping_idle_timeout=ping_interval,
                auto_ping_reply_timeout=ping_timeout,
                auto_ping_strategy=WSAutoPingStrategy.PING_WHEN_IDLE,
                max_frame_size=max_bytes,
                # Status updates are small; the buffer doubles when a big answer comes.
                read_buffer_init_size=4096,
                # The API key must not follow a redirect to another host.
                max_redirects=0,
                # Printers live on the LAN: no proxy (picows never reads one from the
                # environment either). picows has no compression to turn off.
                proxy=None,
            )
    except BaseException:
        link.abandon()
        raise
    return link


class MoonrakerLink(WSListener):
    """One open WebSocket. Messages that are JSON objects go to ``on_message``."""

    def __init__(
        self, name: str, on_message: MessageCallback, ping_timeout: float, max_bytes: int
    ) -> None:
        super().__init__()
        self.name = name
        self._on_message = on_message
        self._ping_timeout = ping_timeout
        self._max_bytes = max_bytes
        self._transport: WSTransport | None = None
        self._abandoned = False
        self._closing = False
        self._pongs: set[asyncio.Future[bool | None]] = set()
        self._fragments: bytearray | None = None
        self._ignored = 0

    # -- picows callbacks --------------------------------------------------------------

    def on_ws_connected(self, transport: WSTransport) -> None:
        self._transport = transport
        if self._abandoned:
            # The upgrade finished just after open_link gave up: nobody owns this socket.
            transport.disconnect(graceful=False)

    def on_ws_frame(self, transport: WSTransport, frame: WSFrame) -> None:
        kind = frame.msg_type
        if frame.fin and kind in _DATA:
            self._deliver(frame.get_payload_as_memoryview())
        elif kind == WSMsgType.PONG:
            transport.notify_user_specific_pong_received()
            for pong in self._pongs:
                if not pong.done():
                    pong.set_result(True)
        elif kind == WSMsgType.CLOSE:
            transport.send_close(WSCloseCode.OK)
            transport.disconnect()
        else:
            self._fragment(frame)

    def is_user_specific_pong(self, frame: WSFrame) -> bool:
        # Every pong reaches on_ws_frame, so that alive() sees it even while picows'
        # keepalive waits for one; on_ws_frame tells the keepalive in turn.
        return False

    def on_ws_disconnected(self, transport: WSTransport) -> None:
        # A keepalive ping that went unanswered is the evidence a waiting ping() looks for.
        answer = False if self._keepalive_failed(transport) else None
        for pong in self._pongs:
            if not pong.done():
                pong.set_result(answer)

    # -- for the session ---------------------------------------------------------------

    def send(self, message: bytes) -> None:
        """Queue one text message (a send on a closed link is dropped: its caller's answer
        fails when the session notices the loss, at once)."""
        if self._transport is not None:
            self._transport.send(WSMsgType.TEXT, message)

    async def ping(self, timeout: float) -> bool | None:
        """``True`` if a pong comes within ``timeout`` s; ``False`` if none does (or the
        keepalive gave up meanwhile); ``None`` if the link is closed or closes otherwise."""
        transport = self._transport
        if transport is None or transport.is_disconnected or transport.is_close_frame_sent:
            return None
        pong: asyncio.Future[bool | None] = asyncio.get_running_loop().create_future()
        self._pongs.add(pong)
        try:
            transport.send_ping()
            return await asyncio.wait_for(pong, timeout)
        except TimeoutError:
            return False
        finally:
            self._pongs.discard(pong)

    async def wait_closed(self) -> None:
        """Wait until the socket is gone, then raise :class:`LinkLost` saying why."""
        transport = self._transport
        if transport is None:
            raise LinkLost("not connected", by_peer=False)
        try:
            await transport.wait_disconnected()
        except WSProtocolError as exc:
            if exc.code == WSCloseCode.MESSAGE_TOO_BIG:
                raise LinkLost(
                    f"message too big (over {self._max_bytes} bytes)", by_peer=False
                ) from exc
            raise LinkLost(f"protocol error: {exc}", by_peer=False) from exc
        handshake = transport.close_handshake
        if handshake is not None and handshake.recv is not None and handshake.recv_then_sent:
            raise LinkLost("Moonraker closed the connection", by_peer=True)
        if self._keepalive_failed(transport):
            raise LinkLost(
                f"keepalive ping timeout (no pong within {self._ping_timeout:g} s)", by_peer=False
            )
        if handshake is not None and handshake.sent is not None:
            raise LinkLost("KyberCore closed the connection", by_peer=False)
        raise LinkLost("the connection dropped without a close frame", by_peer=True)

    async def close(self, timeout: float) -> None:
        """Say goodbye and give Moonraker ``timeout`` s to close; then cut the socket."""
        transport = self._transport
        if transport is None or transport.is_disconnected:
            return
        self._closing = True
        try:
            transport.send_close(WSCloseCode.OK)
            # A peer that stopped answering will not answer a close frame either.
            with contextlib.suppress(Exception):
                async with asyncio.timeout(timeout):
                    await transport.wait_disconnected()
        finally:
            if not transport.is_disconnected:
                transport.disconnect(graceful=False)

    def abandon(self) -> None:
        """open_link gave up: close the socket, now or as soon as the upgrade completes."""
        self._abandoned = True
        if self._transport is not None:
            self._transport.disconnect(graceful=False)

    # -- internals ---------------------------------------------------------------------

    def _keepalive_failed(self, transport: WSTransport) -> bool:
        handshake = transport.close_handshake
        sent = handshake.sent if handshake is not None else None
        # GOING_AWAY is the code of the close picows sends when its keepalive gives up; we
        # never send it ourselves.
        return (
            sent is not None
            and sent.code == WSCloseCode.GOING_AWAY
            and not handshake.recv_then_sent
            and not self._closing
        )

    def _deliver(self, payload: memoryview | bytearray) -> None:
        try:
            message = orjson.loads(payload)
        except orjson.JSONDecodeError:
            self._ignored += 1
            # Once per connection at WARNING: a broken peer must not flood the log.
            log.log(
                logging.WARNING if self._ignored == 1 else logging.DEBUG,
                "%s: ignored a frame that is not JSON (%d on this connection)",
                self.name,
                self._ignored,
            )
            return
        if isinstance(message, dict):
            self._on_message(message)

    def _fragment(self, frame: WSFrame) -> None:
        """A message in several frames (Moonraker sends one, but the protocol allows it)."""
        if frame.msg_type in _DATA:
            self._fragments = bytearray(frame.get_payload_as_memoryview())
            return
        if frame.msg_type != WSMsgType.CONTINUATION or self._fragments is None:
            return
        self._fragments += frame.get_payload_as_memoryview()
        if len(self._fragments) > self._max_bytes:
            self._fragments = None
            # picows closes the link with this code; wait_closed reports it.
            raise WSProtocolError(WSCloseCode.MESSAGE_TOO_BIG, "message too big")
        if frame.fin:
            message, self._fragments = self._fragments, None
            self._deliver(message)
