"""One long-lived Moonraker WebSocket session: JSON-RPC calls, subscription, reconnects.

The session identifies itself as an agent, waits while Klippy starts, subscribes to the
objects it was given and hands every notification to a callback. When the socket drops,
every pending call fails at once with :class:`PrinterUnreachable` and the session
reconnects by itself, forever, with capped exponential backoff and jitter (but every second
or so while a printer that was just healthy refuses connections: a restart); after each
reconnect (and after ``notify_klippy_ready``) it subscribes again.

Klippy's state is what Moonraker last said, in the order it said it: each notification,
and the ``webhooks.state`` of each subscription snapshot as its answer is read. A
``server.info`` answer only fills in while nothing can be subscribed to.

The socket itself is :mod:`kybercore.moonraker.link`; what the session reports is in
:mod:`kybercore.moonraker.events`, its reconnect delays in :mod:`kybercore.moonraker.backoff`,
and the changes it logs in :mod:`kybercore.moonraker.statelog`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Iterator, Mapping
from typing import Any, Final
from urllib.parse import urlsplit

import picows

from kybercore.aio import cancel_and_wait
from kybercore.errors import (
    KlippyNotReady,
    MoonrakerRpcError,
    PrinterAuthFailed,
    PrinterError,
    PrinterUnreachable,
)
from kybercore.moonraker.answers import malformed
from kybercore.moonraker.backoff import Backoff
from kybercore.moonraker.events import (
    ConnectionChanged,
    EventCallback,
    KlippyChanged,
    Notification,
    SessionEvent,
    StatusDelta,
    StatusSnapshot,
)
from kybercore.moonraker.link import Connect, LinkLost, MoonrakerLink, open_link
from kybercore.moonraker.objects import (
    klippy_state_after,
    klippy_state_in,
    snapshot_status,
    status_objects,
    with_klippy_state,
)
from kybercore.moonraker.reach import connect_problem, connection_refused
from kybercore.moonraker.rpc import PendingCalls
from kybercore.moonraker.statelog import StateLog

log = logging.getLogger(__name__)

# Enough for Klippy's `configfile` object, small enough that a runaway frame cannot eat memory.
MAX_FRAME_BYTES: Final = 8 * 1024 * 1024
# A silent peer is noticed within PING_INTERVAL + PING_TIMEOUT seconds: after PING_INTERVAL
# without a byte from it, a ping; no pong within PING_TIMEOUT cuts the link.
PING_INTERVAL: Final = 5.0
PING_TIMEOUT: Final = 5.0
# How long a close frame we send waits for Moonraker's answer before the socket is cut.
# (A silent peer is cut by the keepalive itself, without waiting.)
CLOSE_TIMEOUT: Final = 1.0
# TCP connect plus WebSocket upgrade: a peer that accepts TCP and stalls must not hang us.
OPEN_TIMEOUT: Final = 5.0
CALL_TIMEOUT: Final = 10.0
# While Klippy starts, Moonraker's guide asks clients to poll server.info every 2 s.
KLIPPY_POLL_SECONDS: Final = 2.0
# Wrong credentials will not fix themselves: retry slowly so Moonraker is not hammered.
AUTH_RETRY_SECONDS: Final = 60.0
_SUBSCRIBABLE_STATES: Final = frozenset({"ready", "shutdown", "error"})


class MoonrakerSession:
    """The WebSocket half of a printer's Moonraker client."""

    def __init__(
        self,
        ws_url: str,
        *,
        name: str,
        api_key: str | None,
        subscription: Mapping[str, list[str] | None],
        on_event: EventCallback,
        client_name: str,
        version: str,
        connect: Connect = picows.ws_connect,
        backoff: Backoff | None = None,
    ) -> None:
        self.ws_url = ws_url
        self.name = name
        self._api_key = api_key
        self._subscription = with_klippy_state(subscription)
        self._on_event = on_event
        self._client_name = client_name
        self._version = version
        self._connect = connect
        self._backoff = backoff or Backoff()
        self._calls = PendingCalls(name)
        self._link: MoonrakerLink | None = None
        self._task: asyncio.Task[None] | None = None
        self._klippy_event = asyncio.Event()
        self._states = StateLog(name)
        self._klippy_news = 0
        """How many times a notification or a snapshot told Klippy's state: an answer to a
        ``server.info`` sent before the count last moved is older than what we know."""
        self._up = False
        """This connection got as far as a valid ``server.info``: Moonraker really answered."""
        self._gcode_collectors: list[list[str]] = []
        self.connection = "connecting"
        self.klippy_state = "disconnected"
        self.last_error = ""

    # -- lifecycle ---------------------------------------------------------------------

    def start(self) -> None:
        """Start the background task that keeps the session connected."""
        if self._task is None or self._task.done():
            self._task = asyncio.create_task(self._run(), name=f"moonraker-session:{self.name}")

    async def stop(self) -> None:
        """Close the socket and stop reconnecting."""
        task, self._task = self._task, None
        await cancel_and_wait(task)

    @property
    def connected(self) -> bool:
        """Whether the socket is open now (calls can go over it)."""
        return self._link is not None

    @property
    def running(self) -> bool:
        """Whether the background task is alive."""
        return self._task is not None and not self._task.done()

    # -- JSON-RPC ----------------------------------------------------------------------

    async def call(
        self, method: str, params: Mapping[str, Any] | None = None, timeout: float = CALL_TIMEOUT
    ) -> Any:
        """Send one JSON-RPC request over the socket and return its ``result``."""
        link = self._link
        if link is None:
            raise PrinterUnreachable(
                f"not connected to Moonraker at {self.ws_url} ({self.last_error or 'connecting'})",
                printer=self.name,
            )
        return await self._calls.call(link.send, method, params, timeout)

    async def alive(self, timeout: float) -> bool | None:
        """Whether Moonraker answers a ping within ``timeout`` s right now.

        ``False`` only on evidence that it hangs (a ping on an open socket went unanswered);
        ``None`` when there is no open socket to ask. Moonraker answers pings even while a
        long G-code runs, so this tells a slow command from a frozen host.
        """
        link = self._link
        return None if link is None else await link.ping(timeout)

    @contextlib.contextmanager
    def gcode_responses(self) -> Iterator[list[str]]:
        """The ``notify_gcode_response`` lines that arrive while the block runs, in order.

        Moonraker sends the responses to a ``printer.gcode.script`` call on the socket
        before its answer, so a call awaited inside the block has all of its lines in the
        list once it returns (with any other client's lines from that time, too).
        """
        lines: list[str] = []
        self._gcode_collectors.append(lines)
        try:
            yield lines
        finally:
            # By identity: list.remove() compares contents, and two calls may hold equal lists.
            self._gcode_collectors = [c for c in self._gcode_collectors if c is not lines]

    async def resubscribe(self) -> None:
        """Subscribe again (for example after changing what to watch).

        The snapshot (and the Klippy state in it) is reported as its answer is read, in
        order with the notifications around it: see :meth:`_answered`.
        """
        result = await self.call("printer.objects.subscribe", {"objects": self._subscription})
        if snapshot_status(result) is None:
            raise self._malformed("printer.objects.subscribe", "no 'status' object")

    # -- internals ---------------------------------------------------------------------

    def _malformed(self, method: str, why: str) -> MoonrakerRpcError:
        return malformed(method, why, self.ws_url, self.name)

    def _emit(self, event: SessionEvent) -> None:
        """Hand an event to the owner; its bugs are logged, never allowed to kill the link."""
        try:
            self._on_event(event)
        except Exception:
            log.exception("%s: the session's event handler failed on %s", self.name, event)

    def _unreachable(self, why: str) -> PrinterUnreachable:
        return PrinterUnreachable(
            f"lost the connection to Moonraker at {self.ws_url}: {why}. "
            "KyberCore reconnects by itself; retry when the printer is back online.",
            printer=self.name,
        )

    def _describe(self, exc: BaseException) -> str:
        if isinstance(exc, PrinterError):
            return exc.message
        if isinstance(exc, picows.WSError):
            return str(exc) or type(exc).__name__
        where = urlsplit(self.ws_url).netloc
        return connect_problem(exc, where, OPEN_TIMEOUT if isinstance(exc, TimeoutError) else None)

    def _set_connection(self, connection: str, detail: str = "") -> None:
        if connection != self.connection or detail != self.last_error:
            self.connection = connection
            self.last_error = detail
            if self._task is not None:  # stop() clears it: a deliberate stop is no news
                self._states.connection(connection, detail)
            self._emit(ConnectionChanged(connection, detail))

    def _set_klippy(self, state: str, message: str = "") -> None:
        if state != self.klippy_state:
            if self._task is not None:
                self._states.klippy(state, self.klippy_state, message)
            self.klippy_state = state
            self._emit(KlippyChanged(state, message))

    async def _run(self) -> None:
        while True:
            started = time.monotonic()
            connected_for = 0.0
            retry_after: float | None = None
            peer_left = refused = False
            self._up = False
            link: MoonrakerLink | None = None
            try:
                link = await open_link(
                    self.ws_url,
                    name=self.name,
                    on_message=self._dispatch,
                    headers={"X-Api-Key": self._api_key} if self._api_key else {},
                    connect=self._connect,
                    open_timeout=OPEN_TIMEOUT,
                    ping_interval=PING_INTERVAL,
                    ping_timeout=PING_TIMEOUT,
                    max_bytes=MAX_FRAME_BYTES,
                )
                started = time.monotonic()
                await self._serve(link)
            except asyncio.CancelledError:
                self._drop("KyberCore is stopping this session")
                raise
            except picows.WSInvalidStatusError as exc:
                status = int(exc.response.status) if exc.response else 0
                if status in (401, 403):
                    retry_after = AUTH_RETRY_SECONDS
                    self._drop(f"Moonraker refused the API key (HTTP {status})", "auth_failed")
                else:
                    self._drop(f"Moonraker answered the WebSocket upgrade with HTTP {status}")
            except PrinterAuthFailed as exc:
                retry_after = AUTH_RETRY_SECONDS
                self._drop(exc.message, "auth_failed")
            except LinkLost as exc:
                # Moonraker went away (not: we closed on a fault such as an oversized frame).
                peer_left = exc.by_peer
                self._drop(exc.why)
            except (OSError, TimeoutError, picows.WSError, PrinterError) as exc:
                # OSError: Moonraker's socket refused or reset us (a restart, most likely).
                peer_left = isinstance(exc, OSError)
                refused = connection_refused(exc)
                self._drop(self._describe(exc))
            except Exception as exc:
                # A bug, or a Moonraker answer no one foresaw: the session must outlive it
                # (a dead task would leave the printer shown "online" and frozen forever).
                log.exception("%s: unexpected error in the Moonraker session", self.name)
                self._drop(f"unexpected error in KyberCore's session ({type(exc).__name__})")
            else:
                peer_left = True
                self._drop("Moonraker closed the connection")
            finally:
                # After _drop: pending calls fail at once, not after the goodbye.
                if link is not None:
                    await link.close(CLOSE_TIMEOUT)
            if self._up:
                # Moonraker answered on this connection: if it ended it (a restart), come
                # back at once; refusals soon after are a restart too (see Backoff).
                self._backoff.healthy_session_ended(by_peer=peer_left)
            connected_for = time.monotonic() - started
            delay = self._backoff.next_delay(connected_for, refused=refused)
            await asyncio.sleep(retry_after if retry_after is not None else delay)

    def _drop(self, why: str, connection: str = "offline") -> None:
        """Forget the socket and fail every pending call at once."""
        self._link = None
        self._calls.fail_all(self._unreachable(why))
        self._set_klippy("disconnected")
        self._set_connection(connection, why)

    async def _serve(self, link: MoonrakerLink) -> None:
        """Until the link is lost (:class:`LinkLost`) or following Klippy fails."""
        self._link = link
        closed = asyncio.create_task(link.wait_closed(), name=f"moonraker-link:{self.name}")
        follower = asyncio.create_task(self._identify_and_follow(), name=f"klippy:{self.name}")
        try:
            await asyncio.wait({closed, follower}, return_when=asyncio.FIRST_COMPLETED)
            for task in (follower, closed):
                if task.done():
                    task.result()
        finally:
            self._link = None
            closed.cancel()
            follower.cancel()
            await asyncio.gather(closed, follower, return_exceptions=True)

    async def _identify_and_follow(self) -> None:
        params: dict[str, Any] = {
            "client_name": self._client_name,
            "version": self._version,
            "type": "agent",
            "url": "urn:kybercore",
        }
        if self._api_key:
            params["api_key"] = self._api_key
        try:
            await self.call("server.connection.identify", params)
        except MoonrakerRpcError as exc:
            # Agent names are unique per Moonraker; a stale socket of ours (or another
            # KyberCore) may hold it. Moonraker still accepts this connection as a client.
            if "already registered" not in exc.detail:
                raise
            log.info("%s: agent name in use, continuing as a plain client", self.name)
        self._set_connection("online")
        await self._follow_klippy()

    async def _follow_klippy(self) -> None:
        """Poll ``server.info`` until Klippy can be subscribed to, then wait for news."""
        while True:
            self._klippy_event.clear()
            news = self._klippy_news
            info = await self.call("server.info")
            if not isinstance(info, dict):
                raise self._malformed("server.info", "not an object")
            self._up = True
            state = str(info.get("klippy_state", "disconnected"))
            if info.get("klippy_connected") and state in _SUBSCRIBABLE_STATES:
                try:
                    # The snapshot's webhooks.state, not this server.info, sets the state:
                    # Klippy may have shut down in between.
                    await self.resubscribe()
                except (KlippyNotReady, MoonrakerRpcError) as exc:
                    log.info("%s: subscribe failed, retrying: %s", self.name, exc)
                    await asyncio.sleep(KLIPPY_POLL_SECONDS)
                    continue
                await self._klippy_event.wait()
            else:
                if self._klippy_news == news:  # nothing newer arrived while we asked
                    self._set_klippy(state)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._klippy_event.wait(), KLIPPY_POLL_SECONDS)

    def _dispatch(self, message: dict[str, Any]) -> None:
        if "id" in message and ("result" in message or "error" in message):
            self._calls.answer(message, self._answered)
            return
        method = message.get("method")
        if not isinstance(method, str):
            return
        params = message.get("params")
        params = params if isinstance(params, list) else []
        if method == "notify_status_update":
            if params and isinstance(params[0], dict):
                eventtime = params[1] if len(params) > 1 and isinstance(params[1], float) else 0.0
                delta = status_objects(params[0])
                self._emit(StatusDelta(delta=delta, eventtime=eventtime))
                if "webhooks" in delta:  # rarely: Klippy's state is news only when it moves
                    self._hear_klippy(klippy_state_in(delta))
            return
        if method in ("notify_klippy_ready", "notify_klippy_disconnected"):
            self._klippy_event.set()
        if method.startswith("notify_klippy_"):
            self._hear_klippy(klippy_state_after(self.klippy_state, method, params))
            return
        if method == "notify_gcode_response" and params:
            for lines in self._gcode_collectors:
                lines.append(str(params[0]))
        self._emit(Notification(method, params))

    def _answered(self, method: str, result: Any) -> None:
        """A subscription's answer, handled as it is read: its snapshot and Klippy's state
        in it are newer than every notification before it and older than any after it."""
        status = snapshot_status(result) if method == "printer.objects.subscribe" else None
        if status is not None:
            self._emit(StatusSnapshot(status=status))
            self._hear_klippy(klippy_state_in(status))

    def _hear_klippy(self, state: str | None) -> None:
        """Klippy's state as Moonraker just told it (``None``: it did not say)."""
        if state is not None:
            self._klippy_news += 1
            self._set_klippy(state)
