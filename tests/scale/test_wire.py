"""Errors and outcomes cross a process boundary as themselves: same class, code, message,
reasons, so the front answers exactly as ``kybercore serve`` would. Images cross in base64,
within one NATS message, or are refused with a clear error."""

from __future__ import annotations

import pytest

from kybercore.api.errors import error_status
from kybercore.core.macros import Macro
from kybercore.core.messages import reason
from kybercore.core.validation import Verdict
from kybercore.errors import ActionRejected, MoonrakerRpcError, OutcomeUnknown, UnknownPrinter
from kybercore.fleet.actions import ActionOutcome
from kybercore.fleet.images import Image
from kybercore.fleet.webcams import webcams_of
from kybercore.scale.wire import (
    MAX_IMAGE,
    decode_error,
    decode_image,
    decode_macros,
    decode_outcome,
    decode_verdict,
    decode_webcams,
    dumps,
    encode_error,
    encode_image,
    encode_macros,
    encode_outcome,
    encode_verdict,
    encode_webcams,
    loads,
)

NATS_MAX_PAYLOAD = 1024 * 1024
"""nats-server's default max_payload."""


def test_errors_keep_their_class_and_their_http_answer() -> None:
    for exc in (
        MoonrakerRpcError(404, "No such file", printer="p1"),
        UnknownPrinter("ghost"),
        ActionRejected("Busy.", code="printer_busy", reasons=[{"code": "x", "en": "a"}]),
        OutcomeUnknown("no answer", printer="p1"),
    ):
        back = decode_error(loads(dumps(encode_error(exc))))
        assert type(back) is type(exc)
        assert (back.code, back.message, back.reasons) == (exc.code, exc.message, exc.reasons)
        assert error_status(back) == error_status(exc)


def test_outcomes_and_verdicts_round_trip() -> None:
    started = ActionOutcome("p1", "start", "Started.", response=["ok"])
    outcome = ActionOutcome("p1", "upload", "Uploaded.", start=started)
    assert decode_outcome(loads(dumps(encode_outcome(outcome)))) == outcome
    verdict = Verdict.of([reason("unknown_action", action="fly", valid="start")])
    assert decode_verdict(loads(dumps(encode_verdict(verdict)))) == verdict


def test_images_cross_as_base64_with_their_media_type() -> None:
    image = Image(bytes(range(256)) * 4, "image/png")  # every byte value, NUL included
    back = decode_image(loads(dumps(encode_image(image, "The thumbnail 'x.png'"))))
    assert back == image


def test_the_largest_image_allowed_fits_in_one_nats_message() -> None:
    largest = Image(b"\xff" * MAX_IMAGE, "image/jpeg")
    answer = dumps({"ok": encode_image(largest, "The snapshot of webcam 'cam'")})
    assert len(answer) < NATS_MAX_PAYLOAD - 1024  # with room for headers


def test_a_larger_image_is_refused_with_a_clear_typed_error() -> None:
    too_big = Image(b"\xff" * (MAX_IMAGE + 1), "image/jpeg")
    with pytest.raises(ActionRejected) as refused:
        encode_image(too_big, "fleet-a: the snapshot of webcam 'cam'")
    back = decode_error(loads(dumps(encode_error(refused.value))))
    assert (type(back), back.code) == (ActionRejected, "too_large_for_front")
    assert error_status(back) == (409, "too_large_for_front")
    assert back.message.startswith("fleet-a: the snapshot of webcam 'cam' is 701 kB")
    assert "kybercore serve" in back.message


def test_macros_and_webcams_round_trip() -> None:
    macros = [Macro("PARK", "Move the toolhead away"), Macro("PURGE", "")]
    assert decode_macros(loads(dumps(encode_macros(macros)))) == macros
    cams = webcams_of(
        "http://voron.local:7125",
        [{"name": "cam", "snapshot_url": "/webcam/?action=snapshot", "rotation": 90}],
    )
    assert decode_webcams(loads(dumps(encode_webcams(cams)))) == cams
