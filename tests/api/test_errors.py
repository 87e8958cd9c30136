"""Every KyberCore error maps to one HTTP status, in one place."""

from __future__ import annotations

import json
from typing import Literal

import pytest
from fastapi.exceptions import RequestValidationError

from kybercore.api.errors import error_status
from kybercore.errors import (
    AccessDenied,
    ActionRejected,
    BrokerUnavailable,
    ConfigError,
    DatabaseUnavailable,
    FileNotFound,
    InvalidInput,
    KlippyNotReady,
    KyberCoreError,
    LaunchError,
    MoonrakerRpcError,
    PrinterAuthFailed,
    PrinterTimeout,
    PrinterUnreachable,
    UnknownPrinter,
)


@pytest.mark.parametrize(
    ("error", "status", "code"),
    [
        (UnknownPrinter("x"), 404, "unknown_printer"),
        (ActionRejected("no", code="pause_not_printing"), 409, "pause_not_printing"),
        (KlippyNotReady("wait"), 409, "klippy_not_ready"),
        (InvalidInput("bad"), 422, "invalid_input"),
        (PrinterAuthFailed("key"), 502, "printer_auth_failed"),
        (MoonrakerRpcError(400, "refused"), 502, "moonraker_error"),
        (MoonrakerRpcError(404, "no such file"), 404, "not_found"),
        (PrinterTimeout("slow"), 504, "printer_timeout"),
        (PrinterUnreachable("down"), 503, "printer_unreachable"),
        (ConfigError("broken"), 500, "config_error"),
        (LaunchError("port in use"), 500, "launch_error"),
        (FileNotFound("no such file"), 404, "not_found"),
        (AccessDenied("who?", code="unauthorized"), 401, "unauthorized"),
        (AccessDenied("not you", code="forbidden"), 403, "forbidden"),
        (BrokerUnavailable("no answer"), 503, "broker_unavailable"),
        (DatabaseUnavailable("no answer"), 503, "database_unavailable"),
        (KyberCoreError("other"), 500, "error"),
    ],
)
def test_error_status(error: KyberCoreError, status: int, code: str) -> None:
    assert error_status(error) == (status, code)


def test_messages_name_the_printer_and_what_to_do() -> None:
    error = PrinterUnreachable("connection refused", printer="voron-1")
    assert str(error) == "voron-1: connection refused"
    assert "kybercore printers list" in UnknownPrinter("nope").message


def test_reasons_are_given_at_construction() -> None:
    reason = {"code": "c", "level": "block", "en": "no", "es": "no"}
    assert InvalidInput("bad", reasons=[reason]).reasons == (reason,)
    assert ActionRejected("no", code="x", reasons=[reason]).reasons == (reason,)
    assert PrinterUnreachable("down", printer="p", reasons=[reason]).reasons == (reason,)


async def test_field_errors_come_in_spanish_too() -> None:
    """What a Spanish form shows: our validators' own Spanish, pydantic's kinds translated
    (an enum lists its values), never an English sentence inside a Spanish one."""
    from pydantic import BaseModel, ValidationError

    from kybercore.api.errors import validation_error_handler
    from kybercore.registry.models import PrinterCreate

    class Pick(BaseModel):
        mode: Literal["tiles", "table"]
        count: int

    errors = []
    for model, data in (
        (PrinterCreate, {"name": "X", "moonraker_url": "ftp://x"}),
        (PrinterCreate, {"name": "X", "moonraker_url": "http://x:7125/server/info"}),
        (Pick, {"mode": "grid", "count": "many"}),
        (Pick, {"mode": "tiles", "count": 1.5}),
        (Pick, []),
    ):
        with pytest.raises(ValidationError) as invalid:
            model.model_validate(data)
        errors += invalid.value.errors()
    answer = await validation_error_handler(None, RequestValidationError(errors))  # type: ignore[arg-type]
    listed = json.loads(answer.body)["error"]["fields"]
    fields = {f["field"]: f["es"] for f in listed}
    spanish = [f["es"] for f in listed]
    assert spanish[0] == "la URL debe empezar por http:// o https://, no por 'ftp:'"
    assert spanish[1].startswith("la URL debe ser solo la dirección de Moonraker, sin ruta")
    assert fields["mode"] == "Debe ser uno de: 'tiles' o 'table'."
    assert fields["count"] == "Debe ser un número entero."
    assert spanish[-2:] == ["Debe ser un número entero.", "Debe ser un objeto."]
    for text in spanish:
        assert "must" not in text
        assert "should" not in text
