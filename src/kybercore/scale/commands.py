"""Actions across processes: a front asks a printer's owner on ``kc.cmd.<printer id>``.

The exchange, and what each way it can end means:

1. The front publishes the command with a unique id, the slot epoch it knows
   (``KC-Epoch``) and the time it stops waiting for an acknowledgement.
2. NATS answers "no responders" when no worker holds the printer (one died, or slots are
   moving): nothing was sent to the printer, so the front answers 503 "owner moving" at once.
3. The owner checks it may act (its lease is fresh, the epoch is not newer than its own,
   the front still waits, the id is new) and acknowledges; or refuses with "owner moving".
4. It runs the command on its :class:`FleetService` and answers with the outcome or the
   error, exactly as ``kybercore serve`` would have.

No acknowledgement, or no outcome in time, means the outcome is unknown (504): the command
may have run. It is never retried on its own: a start, a G-code or an e-stop sent twice
can do harm.
"""

from __future__ import annotations

import asyncio
import logging
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Final

from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import MaxPayloadError

from kybercore.errors import (
    ActionRejected,
    KyberCoreError,
    OutcomeUnknown,
    OwnerMoving,
)
from kybercore.fleet.service import FleetService
from kybercore.scale.broker import require_connected
from kybercore.scale.ops import OPS
from kybercore.scale.wire import (
    EPOCH_HEADER,
    command_subject,
    decode_error,
    dumps,
    encode_error,
    encode_outcome,
    loads,
)

if TYPE_CHECKING:
    from kybercore.scale.jobfiles import JobFileBucket
    from kybercore.scale.streams import StreamRelay
    from kybercore.scale.uploads import Uploads

log = logging.getLogger(__name__)

ACK_SECONDS: Final = 5.0
"""How long a front waits for the owner to take a command (it takes it at once: longer
means the owner is paused or cut off)."""
ANSWER_SECONDS: Final = 660.0
"""How long a taken command may run: a G-code that heats waits up to Moonraker's limit."""
REMEMBERED_IDS: Final = 4096
CHECK_PRINTER: Final = "Check the printer (its console and state) before sending it again."


def _moving(printer_id: str) -> OwnerMoving:
    return OwnerMoving(
        "no KyberCore worker answers for this printer right now (one stopped, printers are "
        "being shared out again, or the printer's site is cut off from this server). Nothing "
        "was sent to it; retry in a few seconds.",
        printer=printer_id,
    )


def _unknown(printer_id: str, what: str, check: str) -> OutcomeUnknown:
    return OutcomeUnknown(
        f"the printer's KyberCore worker {what}, so whether the command ran is unknown. {check}",
        printer=printer_id,
    )


def _too_large(printer_id: str, op: str, size: int) -> ActionRejected:
    return ActionRejected(
        f"{printer_id}: the command '{op}' ran on the printer's worker, but its answer is "
        f"{size / 1024:.0f} kB, more than one NATS message may carry (the server's "
        "max_payload), so a KyberCore front cannot relay it. Use `kybercore serve`, or the "
        "printer's own Mainsail or Fluidd, for this.",
        code="too_large_for_front",
    )


async def send_command(
    nc: Client,
    printer_id: str,
    op: str,
    args: Mapping[str, Any],
    *,
    epoch: int = 0,
    answer_timeout: float = ANSWER_SECONDS,
    check: str = CHECK_PRINTER,
) -> Any:
    """Run ``op`` on the printer's owner; its result, or the error it raised (OwnerMoving
    when nobody holds the printer, BrokerUnavailable when this process is not connected to
    the broker, OutcomeUnknown when the owner went silent: ``check`` says what to look at
    before sending it again)."""
    # An e-stop or a start held by nats-py would run after its caller was told it failed.
    require_connected(nc, f"nothing was sent to the printer {printer_id}")
    inbox = nc.new_inbox()
    sub = await nc.subscribe(inbox, max_msgs=2)
    try:
        request = {
            "id": uuid.uuid4().hex, "op": op, "args": dict(args),
            "deadline": time.time() + ACK_SECONDS,
        }  # fmt: skip
        headers = {EPOCH_HEADER: str(epoch)}
        await nc.publish(command_subject(printer_id), dumps(request), reply=inbox, headers=headers)
        try:
            ack = await sub.next_msg(timeout=ACK_SECONDS)
        except TimeoutError:
            took = f"did not take it within {ACK_SECONDS:.0f} s"
            if not nc.is_connected:
                took = "could not be reached: this process lost the NATS broker meanwhile"
            raise _unknown(printer_id, took, check) from None
        if ack.headers and ack.headers.get("Status") == "503":
            raise _moving(printer_id)
        body = loads(ack.data)
        if "ack" not in body:
            return _result(body)
        try:
            answer = await sub.next_msg(timeout=answer_timeout)
        except TimeoutError:
            waited = f"took it but did not answer in {answer_timeout:.0f} s"
            raise _unknown(printer_id, waited, check) from None
        return _result(loads(answer.data))
    finally:
        await sub.unsubscribe()


def _result(body: dict[str, Any]) -> Any:
    if "error" in body:
        raise decode_error(body["error"])
    return body["ok"]


class CommandRunner:
    """A worker's side: takes commands for the printers it owns and runs them."""

    def __init__(
        self,
        service: FleetService,
        epoch_of: Callable[[str], int | None],
        *,
        uploads: Uploads | None = None,
        jobfiles: JobFileBucket | None = None,
        streams: StreamRelay | None = None,
    ) -> None:
        """``epoch_of(printer_id)``: the printer's slot epoch while this worker may act for
        it (the lease is fresh), else None. ``uploads``: where uploaded files wait;
        ``jobfiles``: where the queue's files are shared; ``streams``: what relays webcam
        streams (without them, the ``upload``, ``fetch_file`` and ``camera_stream``
        commands are unknown here)."""
        self._service = service
        self._uploads = uploads
        self._jobfiles = jobfiles
        self._streams = streams
        self._epoch_of = epoch_of
        self._seen: OrderedDict[str, None] = OrderedDict()
        self._running: set[asyncio.Task[None]] = set()

    async def stop(self) -> None:
        """Cancel the commands still running, and the webcam streams being relayed."""
        for task in list(self._running):
            task.cancel()
        await asyncio.gather(*self._running, return_exceptions=True)
        if self._streams is not None:
            await self._streams.stop()

    async def on_message(self, msg: Msg) -> None:
        """A command arrived: refuse it, or acknowledge it and run it in the background
        (one printer's long G-code must not hold up the next command)."""
        printer_id = msg.subject.split(".", 2)[2]
        request = loads(msg.data)
        epoch = self._epoch_of(printer_id)
        known = int((msg.headers or {}).get(EPOCH_HEADER, "0") or 0)
        if epoch is None or known > epoch:
            await msg.respond(dumps({"error": encode_error(_moving(printer_id))}))
            return
        if time.time() > float(request["deadline"]) or request["id"] in self._seen:
            # The front stopped waiting (it reported "unknown"), or this is a copy: running
            # it now would surprise whoever sent it.
            log.warning("%s: command %s refused (late or repeated)", printer_id, request["id"])
            return
        self._seen[request["id"]] = None
        while len(self._seen) > REMEMBERED_IDS:
            self._seen.popitem(last=False)
        await msg.respond(dumps({"ack": True}))
        task = asyncio.create_task(self._run(msg, printer_id, request))
        self._running.add(task)
        task.add_done_callback(self._running.discard)

    async def _run(self, msg: Msg, printer_id: str, request: dict[str, Any]) -> None:
        try:
            result = await self._call(printer_id, request["op"], request["args"])
            body: dict[str, Any] = {"ok": result}
        except KyberCoreError as exc:
            body = {"error": encode_error(exc)}
        except Exception as exc:
            log.exception("%s: command %s failed", printer_id, request["op"])
            error = KyberCoreError(f"{printer_id}: the command failed inside KyberCore ({exc}).")
            body = {"error": encode_error(error)}
        data = dumps(body)
        try:
            await msg.respond(data)
        except MaxPayloadError:
            # Said in an answer that fits: else the front would wait for the outcome in vain.
            too_large = _too_large(printer_id, request["op"], len(data))
            await msg.respond(dumps({"error": encode_error(too_large)}))

    async def _call(self, printer_id: str, op: str, args: dict[str, Any]) -> Any:
        if op == "upload" and self._uploads is not None:
            # Not in OPS: it needs the worker's object store as well as its FleetService.
            return encode_outcome(await self._uploads.receive(self._service, printer_id, args))
        if op == "fetch_file" and self._jobfiles is not None:
            # Not in OPS either: the file goes into the broker's object store.
            return await self._jobfiles.offer(self._service, printer_id, str(args["path"]))
        if op == "camera_stream" and self._streams is not None:
            # Not in OPS either: the stream goes on after the answer, over NATS.
            return await self._streams.open(self._service, printer_id, args)
        run = OPS.get(op)
        if run is None:
            raise KyberCoreError(f"Unknown command '{op}': this worker is older than its front.")
        return await run(self._service, printer_id, args)
