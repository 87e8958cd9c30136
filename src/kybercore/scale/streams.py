"""A webcam's live MJPEG stream through a front: the printer's owner relays it over NATS.

A stream is endless, so it does not fit one command and its one answer (:mod:`.commands`):

1. The front subscribes to a fresh inbox and sends the command ``camera_stream`` naming it.
2. The owner opens the camera's stream as ``kybercore serve`` does (its limit of streams
   per printer included) and answers with the content type. An error (no such webcam, too
   many streams, no MJPEG from the camera) is the answer instead, so the browser gets it
   as an HTTP error, not as a 200 that breaks off. The answer also gives the owner's window
   (below).
3. The owner publishes the camera's bytes to the inbox, numbered (``KC-Seq``), with a
   status inbox of its own as the reply subject. The front hands them to the browser and,
   every quarter of the window, tells the owner on that subject how far it has read.

How it ends:

- the browser leaves: the front unsubscribes, and NATS answers the owner's next chunk with
  "no responders" at once;
- the browser or the front stops reading: the owner keeps at most a window
  (:data:`WINDOW_BYTES`) unread in flight and gives up after :data:`STALL_SECONDS` without
  news;
- the camera ends its stream or goes silent, the owner loses the printer's lease, or the
  worker stops: the owner sends an end marker (``KC-End``) saying why;
- the owner goes silent (it died): the front ends after :data:`STALL_SECONDS`;
- a gap in the numbers (a chunk lost on the way) ends it too: what follows would be a cut
  picture.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator, Callable, Mapping
from typing import Any, Final

import httpx
import nats.errors
from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.aio.subscription import Subscription

from kybercore.errors import InvalidInput
from kybercore.fleet.service import FleetService
from kybercore.fleet.webcams import CameraStream
from kybercore.scale.commands import send_command
from kybercore.scale.wire import dumps, loads

log = logging.getLogger(__name__)

OP: Final = "camera_stream"
SEQ_HEADER: Final = "KC-Seq"
END_HEADER: Final = "KC-End"
INBOX_PREFIX: Final = "_INBOX."
"""Where a front may ask to be sent a stream (nats-py's inboxes): a command must not make
an owner publish on any other subject."""
WINDOW_BYTES: Final = 4 * 1024 * 1024
"""Bytes an owner sends ahead of what the browser has read: a few seconds of a camera."""
STALL_SECONDS: Final = 30.0
"""A stream with nothing moving this long is over (the camera's own read timeout too)."""
OPEN_SECONDS: Final = 30.0
"""How long opening the camera's stream may take on the owner."""
RELOAD: Final = "Reload the page to try the stream again."


async def open_stream(nc: Client, printer_id: str, name: str, *, epoch: int) -> RelayedStream:
    """The front's side: the webcam ``name``'s stream, relayed by the printer's owner (its
    errors are raised here, as :func:`~kybercore.scale.commands.send_command` raises them)."""
    inbox = nc.new_inbox()
    # Room for twice the window: more is only ever there if the owner is broken.
    sub = await nc.subscribe(inbox, pending_bytes_limit=2 * WINDOW_BYTES)
    try:
        opened = await send_command(
            nc, printer_id, OP, {"name": name, "to": inbox},
            epoch=epoch, answer_timeout=OPEN_SECONDS, check=RELOAD,
        )  # fmt: skip
    except BaseException:
        await sub.unsubscribe()
        raise
    window = min(int(opened["window"]), WINDOW_BYTES)
    return RelayedStream(str(opened["content_type"]), nc, sub, printer_id, window // 4)


class RelayedStream:
    """A stream as a front receives it (a :class:`~kybercore.fleet.webcams.CameraStream`)."""

    def __init__(
        self, content_type: str, nc: Client, sub: Subscription, printer_id: str, ack_every: int
    ) -> None:
        """``ack_every``: bytes read between two acknowledgements to the owner."""
        self.content_type = content_type
        self.ended = ""
        """Why the stream ended, once it has."""
        self._nc = nc
        self._sub = sub
        self._printer_id = printer_id
        self._ack_every = max(1, ack_every)
        self._open = True

    def __aiter__(self) -> AsyncIterator[bytes]:
        return self._chunks()

    async def aclose(self) -> None:
        """Stop receiving: the owner hears "no responders" at its next chunk and stops."""
        if self._open:
            self._open = False
            with contextlib.suppress(nats.errors.Error):
                await self._sub.unsubscribe()

    async def _chunks(self) -> AsyncIterator[bytes]:
        expected, read, told = 0, 0, 0
        while self._open:
            try:
                msg = await self._sub.next_msg(timeout=STALL_SECONDS)
            except TimeoutError:
                self._end("the printer's worker went silent")
                return
            except nats.errors.Error as exc:  # the front's connection closed
                self._end(f"the broker connection broke ({exc})")
                return
            headers = msg.headers or {}
            if END_HEADER in headers:
                self._end(headers[END_HEADER])
                return
            if headers.get(SEQ_HEADER) != str(expected):
                self._end("a chunk was lost on the way")
                return
            expected += 1
            yield msg.data
            read += len(msg.data)
            if read - told >= self._ack_every and msg.reply:
                told = read
                with contextlib.suppress(nats.errors.Error):
                    await self._nc.publish(msg.reply, dumps({"read": read}))

    def _end(self, why: str) -> None:
        self.ended = why
        log.info("%s: a webcam stream through the front ended: %s", self._printer_id, why)


class StreamRelay:
    """The owner's side: relays the streams fronts open, while it holds the printer."""

    def __init__(
        self,
        nc: Client,
        epoch_of: Callable[[str], int | None],
        *,
        window: int = WINDOW_BYTES,
        stall: float = STALL_SECONDS,
    ) -> None:
        """``epoch_of``: as :class:`~kybercore.scale.commands.CommandRunner`'s (None: the
        worker may no longer act for the printer, so it stops relaying its camera)."""
        self._nc = nc
        self._epoch_of = epoch_of
        self._window = window
        self._stall = stall
        self._running: set[asyncio.Task[None]] = set()

    @property
    def relaying(self) -> int:
        """Streams being relayed now."""
        return len(self._running)

    async def open(self, service: FleetService, printer_id: str, args: Mapping[str, Any]) -> Any:
        """Open the camera's stream and relay it to ``args["to"]`` in the background; the
        answer is its content type."""
        to = str(args["to"])
        if not to.startswith(INBOX_PREFIX):
            raise InvalidInput(f"A stream goes to a reply inbox ({INBOX_PREFIX}…), not '{to}'.")
        stream = await service.camera_stream(printer_id, str(args["name"]))
        task = asyncio.create_task(self._relay(printer_id, to, stream), name=f"{OP}-{printer_id}")
        self._running.add(task)
        task.add_done_callback(self._running.discard)
        return {"content_type": stream.content_type, "window": self._window}

    async def stop(self) -> None:
        """Stop relaying (each front is told the stream ended)."""
        for task in list(self._running):
            task.cancel()
        await asyncio.gather(*self._running, return_exceptions=True)

    async def _relay(self, printer_id: str, to: str, stream: CameraStream) -> None:
        flow = _Flow()
        status = self._nc.new_inbox()
        try:
            sub = await self._nc.subscribe(status, cb=flow.heard)
        except nats.errors.Error as exc:
            log.info("%s: a webcam stream could not be relayed: %r", printer_id, exc)
            await stream.aclose()
            return
        why = "the printer's worker stopped"
        # The front may leave while the camera is between frames: "no responders" ends the
        # relay then, not the camera's next chunk.
        pump = asyncio.create_task(self._pump(printer_id, to, status, stream, flow))
        gone = asyncio.create_task(flow.left.wait())
        try:
            await asyncio.wait({pump, gone}, return_when=asyncio.FIRST_COMPLETED)
            why = pump.result() if pump.done() else ""
        except Exception:
            log.exception("%s: relaying a webcam stream failed", printer_id)
            why = "KyberCore failed relaying it"
        finally:
            for task in (pump, gone):
                task.cancel()
            await asyncio.gather(pump, gone, return_exceptions=True)
            await stream.aclose()
            with contextlib.suppress(nats.errors.Error):
                if why:
                    await self._nc.publish(to, b"", headers={END_HEADER: why})
                await sub.unsubscribe()

    async def _pump(
        self, printer_id: str, to: str, status: str, stream: CameraStream, flow: _Flow
    ) -> str:
        """Publish the camera's bytes until the stream should end; why, for the front
        ("" when it is gone and needs no word)."""
        limit = max(1, self._nc.max_payload // 2)  # headers and all, well inside one message
        seq = 0
        try:
            async for chunk in stream:
                for start in range(0, len(chunk), limit):
                    if not await flow.room(self._window, self._stall):
                        return "" if flow.left.is_set() else "the browser stopped reading"
                    if self._epoch_of(printer_id) is None:
                        return "the printer moved to another worker"
                    part = chunk[start : start + limit]
                    headers = {SEQ_HEADER: str(seq)}
                    await self._nc.publish(to, part, reply=status, headers=headers)
                    flow.sent += len(part)
                    seq += 1
        except httpx.HTTPError as exc:  # the camera's connection broke, or it went silent
            log.info("%s: a webcam stream broke off: %r", printer_id, exc)
            return "the camera stopped sending"
        except nats.errors.Error as exc:
            log.info("%s: a webcam stream could not be relayed: %r", printer_id, exc)
            return "the broker connection broke"
        return "the camera ended its stream"


class _Flow:
    """How far the front has read, from its acknowledgements and NATS's "no responders"."""

    def __init__(self) -> None:
        self.sent = 0
        self.read = 0
        self.left = asyncio.Event()
        """Nobody subscribes to the stream's inbox any more."""
        self._news = asyncio.Event()

    async def heard(self, msg: Msg) -> None:
        if msg.headers and msg.headers.get("Status") == "503":
            self.left.set()
        else:
            with contextlib.suppress(ValueError, TypeError, KeyError):
                self.read = max(self.read, int(loads(msg.data)["read"]))
        self._news.set()

    async def room(self, window: int, stall: float) -> bool:
        """Whether a chunk may go: the front is there and has read enough of the rest."""
        while not self.left.is_set() and self.sent - self.read >= window:
            self._news.clear()
            try:
                await asyncio.wait_for(self._news.wait(), stall)
            except TimeoutError:
                return False
        return not self.left.is_set()
