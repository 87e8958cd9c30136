"""What KyberCore's processes say to each other over NATS: the subjects, and how outcomes,
verdicts, errors and what a front reads (macros, webcams, images) cross a process boundary
intact.

An error raised in a worker reaches the front as the same class with the same code,
message and reasons, so the one HTTP mapping (:mod:`kybercore.api.errors`) answers exactly
as ``kybercore serve`` would.
"""

from __future__ import annotations

import base64
import dataclasses
import math
from typing import Any, Final

import orjson

from kybercore import errors
from kybercore.core.macros import Macro
from kybercore.core.messages import Reason
from kybercore.core.validation import Verdict
from kybercore.fleet.actions import ActionOutcome
from kybercore.fleet.images import Image
from kybercore.fleet.webcams import Webcam
from kybercore.scale.slots import DEFAULT_SITE, SlotRef, site_of_token, site_token

EPOCH_HEADER: Final = "KC-Epoch"
"""The slot epoch a front knows for the printer: a worker holding another epoch refuses."""
MAX_IMAGE: Final = 700 * 1024
"""Bytes of an image a worker sends a front: in base64 (4/3 as long) with its envelope, it
stays within NATS's default limit of 1 MiB per message."""


def patch_subject(slot: int | str, site: str = DEFAULT_SITE) -> str:
    """Where a slot's owner publishes its per-tick patch batches (``*``, ``*``: every slot
    of every site)."""
    return f"kc.s.{site_token(site)}.{slot}.patch"


def slot_of_subject(subject: str) -> SlotRef:
    """The site and slot a :func:`patch_subject` or :func:`snapshot_subject` names."""
    _kc, _s, site, slot, _patch = subject.split(".")
    return SlotRef(site_of_token(site), int(slot))


def snapshot_subject(slot: int, site: str = DEFAULT_SITE) -> str:
    """Where a slot's owner answers with the full views of the slot's printers."""
    return f"kc.s.{site_token(site)}.{slot}.snap"


def command_subject(printer_id: str) -> str:
    """Where a printer's owner takes its commands (request/reply)."""
    return f"kc.cmd.{printer_id}"


def console_subject(printer_id: str) -> str:
    """Where a printer's owner publishes its G-code responses."""
    return f"kc.gcode.{printer_id}"


def dumps(value: Any) -> bytes:
    """JSON for the wire."""
    return orjson.dumps(value)


def loads(data: bytes) -> Any:
    """JSON from the wire."""
    return orjson.loads(data)


# -- errors --------------------------------------------------------------------------------

# Plain attributes some errors carry (rpc_code, printer, state...): they travel too.
_SIMPLE = (str, int, float, bool, type(None))


def _error_classes() -> dict[str, type[errors.KyberCoreError]]:
    found: dict[str, type[errors.KyberCoreError]] = {}
    pending: list[type[errors.KyberCoreError]] = [errors.KyberCoreError]
    while pending:
        kind = pending.pop()
        found[kind.__name__] = kind
        pending.extend(kind.__subclasses__())
    return found


def encode_error(exc: errors.KyberCoreError) -> dict[str, Any]:
    """``exc`` as plain data."""
    attrs = {
        k: v
        for k, v in vars(exc).items()
        if k not in ("message", "reasons") and isinstance(v, _SIMPLE)
    }
    return {
        "type": type(exc).__name__,
        "code": exc.code,
        "message": exc.message,
        "reasons": list(exc.reasons),
        "attrs": attrs,
    }


def decode_error(data: dict[str, Any]) -> errors.KyberCoreError:
    """The error :func:`encode_error` described, as its own class (a class this process
    does not know becomes a plain KyberCoreError with the same code and message)."""
    kind = _error_classes().get(str(data.get("type")), errors.KyberCoreError)
    exc = kind.__new__(kind)
    errors.KyberCoreError.__init__(exc, str(data.get("message", "")), reasons=data["reasons"])
    for name, value in dict(data.get("attrs") or {}).items():
        setattr(exc, name, value)
    exc.code = str(data.get("code") or exc.code)
    return exc


# -- outcomes and verdicts -------------------------------------------------------------------


def encode_outcome(outcome: ActionOutcome) -> dict[str, Any]:
    """An action's outcome as plain data."""
    return {
        "printer_id": outcome.printer_id,
        "action": outcome.action,
        "message": outcome.message,
        "error": encode_error(outcome.error) if outcome.error else None,
        "reasons": outcome.reasons,
        "start": encode_outcome(outcome.start) if outcome.start else None,
        "response": outcome.response,
    }


def decode_outcome(data: dict[str, Any]) -> ActionOutcome:
    """The outcome :func:`encode_outcome` described."""
    return ActionOutcome(
        printer_id=data["printer_id"],
        action=data["action"],
        message=data["message"],
        error=decode_error(data["error"]) if data.get("error") else None,
        reasons=list(data.get("reasons") or []),
        start=decode_outcome(data["start"]) if data.get("start") else None,
        response=list(data.get("response") or []),
    )


def encode_verdict(verdict: Verdict) -> dict[str, Any]:
    """A validation verdict as plain data."""
    return {"reasons": [vars(r) for r in verdict.reasons]}


def decode_verdict(data: dict[str, Any]) -> Verdict:
    """The verdict :func:`encode_verdict` described."""
    return Verdict.of(Reason(**r) for r in data["reasons"])


# -- reads: macros, webcams, images ----------------------------------------------------------


def encode_macros(macros: list[Macro]) -> list[dict[str, Any]]:
    """A printer's macros as plain data."""
    return [dataclasses.asdict(m) for m in macros]


def decode_macros(data: list[dict[str, Any]]) -> list[Macro]:
    """The macros :func:`encode_macros` described."""
    return [Macro(name=str(m["name"]), description=str(m["description"])) for m in data]


def encode_webcams(cameras: list[Webcam]) -> list[dict[str, Any]]:
    """A printer's webcams as plain data."""
    return [dataclasses.asdict(c) for c in cameras]


def decode_webcams(data: list[dict[str, Any]]) -> list[Webcam]:
    """The webcams :func:`encode_webcams` described."""
    return [Webcam(**c) for c in data]


def encode_image(image: Image, what: str) -> dict[str, Any]:
    """An image as plain data (its bytes in base64); ``what`` names it ("The thumbnail
    'x.png'") in the refusal of one over :data:`MAX_IMAGE` bytes, which could not cross."""
    size = len(image.content)
    if size > MAX_IMAGE:
        raise errors.ActionRejected(
            f"{what} is {math.ceil(size / 1024)} kB; a KyberCore front relays images of at most "
            f"{MAX_IMAGE // 1024} kB from the printer's worker (NATS's message limit). Open "
            "it with `kybercore serve`, or the printer's own Mainsail or Fluidd.",
            code="too_large_for_front",
        )
    encoded = base64.b64encode(image.content).decode("ascii")
    return {"media_type": image.media_type, "base64": encoded}


def decode_image(data: dict[str, Any]) -> Image:
    """The image :func:`encode_image` described."""
    content = base64.b64decode(str(data["base64"]), validate=True)
    return Image(content=content, media_type=str(data["media_type"]))
