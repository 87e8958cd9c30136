"""Errors and outcomes cross a process boundary as themselves: same class, code, message,
reasons, so the front answers exactly as ``kybercore serve`` would."""

from __future__ import annotations

from kybercore.api.errors import error_status
from kybercore.core.messages import reason
from kybercore.core.validation import Verdict
from kybercore.errors import ActionRejected, MoonrakerRpcError, OutcomeUnknown, UnknownPrinter
from kybercore.fleet.actions import ActionOutcome
from kybercore.scale.wire import (
    decode_error,
    decode_outcome,
    decode_verdict,
    dumps,
    encode_error,
    encode_outcome,
    encode_verdict,
    loads,
)


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
