"""The one place where errors become HTTP answers: the status map and the error envelope.

Every error KyberCore answers has the same shape::

    {"error": {"code": "...", "message": "...", "reasons": [...], "fields": [...]?}}

``code`` is the error's stable name (:attr:`KyberCoreError.code`), ``message`` says what
to do, ``reasons`` are validation reasons (en/es) and ``fields`` per-field problems of a
request that did not validate.

The exception handlers the app registers are here too, so every error a route raises, and
every request FastAPI refuses, leaves in that envelope.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from typing import Any, Final

import orjson
from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import Response
from starlette.exceptions import HTTPException as StarletteHTTPException

from kybercore.errors import (
    AccessDenied,
    ActionRejected,
    BrokerUnavailable,
    ChannelNotFound,
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
from kybercore.registry.models import SPANISH

log = logging.getLogger(__name__)

# Most specific first: PrinterTimeout is a PrinterUnreachable.
_STATUSES: Final[tuple[tuple[type[KyberCoreError], int], ...]] = (
    (UnknownPrinter, 404),
    (ChannelNotFound, 404),
    (FileNotFound, 404),
    (ActionRejected, 409),
    (KlippyNotReady, 409),
    (InvalidInput, 422),
    (PrinterAuthFailed, 502),
    (MoonrakerRpcError, 502),
    (PrinterTimeout, 504),
    (PrinterUnreachable, 503),
    (BrokerUnavailable, 503),
    (DatabaseUnavailable, 503),
    (ConfigError, 500),
    (LaunchError, 500),
)
_ACCESS: Final = {"unauthorized": 401, "forbidden": 403}
NEVER_PRINTABLE: Final = "never_printable"
"""The queue's refusal of a job no printer of the fleet could ever print."""


def error_status(exc: KyberCoreError) -> tuple[int, str]:
    """HTTP status and the stable error code for ``exc``."""
    if isinstance(exc, AccessDenied):
        return _ACCESS[exc.code], exc.code
    if isinstance(exc, MoonrakerRpcError) and exc.rpc_code == 404:
        return 404, "not_found"  # a file or object the printer does not have
    if isinstance(exc, ActionRejected) and exc.code == NEVER_PRINTABLE:
        return 422, exc.code  # the job as asked, not the fleet's state, is what to change
    for kind, status in _STATUSES:
        if isinstance(exc, kind):
            return status, exc.code
    return 500, exc.code


def error_body(
    code: str,
    message: str,
    reasons: Iterable[Mapping[str, str]] = (),
    fields: list[dict[str, str]] | None = None,
) -> dict[str, Any]:
    """The error envelope, as a dict (bulk results embed it per printer)."""
    error: dict[str, Any] = {"code": code, "message": message, "reasons": list(reasons)}
    if fields is not None:
        error["fields"] = fields
    return {"error": error}


def error_response(
    status: int,
    code: str,
    message: str,
    reasons: Iterable[Mapping[str, str]] = (),
    *,
    fields: list[dict[str, str]] | None = None,
    headers: Mapping[str, str] | None = None,
) -> Response:
    """The error envelope as an HTTP answer."""
    return Response(
        orjson.dumps(error_body(code, message, reasons, fields)),
        status_code=status,
        media_type="application/json",
        headers=headers,
    )


def kybercore_error_response(exc: KyberCoreError) -> Response:
    """The answer for any KyberCore error: its status, code, message and reasons."""
    status, code = error_status(exc)
    return error_response(status, code, exc.message, exc.reasons)


async def kybercore_error_handler(_request: Request, exc: KyberCoreError) -> Response:
    """Exception handler: a KyberCore error a route raised."""
    return kybercore_error_response(exc)


# Spanish for the validation errors people meet in forms; anything else gets the generic one.
_ES_FIELD_ERRORS: Final = {
    "missing": "Falta este campo.",
    "string_too_short": "Es demasiado corto.",
    "string_too_long": "Es demasiado largo.",
    "string_pattern_mismatch": "El formato no es válido.",
    "extra_forbidden": "Este campo no existe.",
    "greater_than": "El valor es demasiado pequeño.",
    "greater_than_equal": "El valor es demasiado pequeño.",
    "less_than": "El valor es demasiado grande.",
    "less_than_equal": "El valor es demasiado grande.",
    "too_long": "Hay demasiados elementos.",
    "too_short": "Faltan elementos.",
    "enum": "Debe ser uno de: {expected}.",
    "literal_error": "Debe ser uno de: {expected}.",
    "int_parsing": "Debe ser un número entero.",
    "int_type": "Debe ser un número entero.",
    "int_from_float": "Debe ser un número entero.",
    "float_parsing": "Debe ser un número.",
    "float_type": "Debe ser un número.",
    "bool_parsing": "Debe ser true o false.",
    "bool_type": "Debe ser true o false.",
    "string_type": "Debe ser un texto.",
    "list_type": "Debe ser una lista.",
    "dict_type": "Debe ser un objeto.",
    "model_type": "Debe ser un objeto.",
    "model_attributes_type": "Debe ser un objeto.",
    "finite_number": "Debe ser un número finito.",
    "datetime_parsing": "Debe ser una fecha y hora válida.",
    "datetime_from_date_parsing": "Debe ser una fecha y hora válida.",
}


def _spanish(kind: str, english: str, context: Mapping[str, Any]) -> str:
    """A field error in Spanish: the validator's own text, else the kind's, else a generic
    one quoting the English."""
    if context.get(SPANISH):
        return str(context[SPANISH])
    template = _ES_FIELD_ERRORS.get(kind)
    if template is None:
        return f"El valor no es válido ({english})."
    # pydantic's "expected" reads "'a', 'b' or 'c'": in Spanish the list joins with "o".
    expected = str(context.get("expected", "")).replace(" or ", " o ")
    return template.replace("{expected}", expected)


async def validation_error_handler(_request: Request, exc: RequestValidationError) -> Response:
    """Exception handler: a request that did not validate, field by field in en/es."""
    # Built from locations and messages only: the input itself may hold an API key.
    fields = []
    for error in exc.errors():
        kind = str(error.get("type", ""))
        if kind == "json_invalid":
            fields.append(_not_json(error))
            continue
        where = ".".join(str(part) for part in error.get("loc", ()) if part != "body") or "body"
        message = str(error.get("msg", "invalid"))
        spanish = _spanish(kind, message, error.get("ctx") or {})
        fields.append({"field": where, "en": message, "es": spanish})
    summary = "; ".join(f"{f['field']}: {f['en']}" for f in fields)
    return error_response(422, "invalid_input", f"Invalid request. {summary}", fields=fields)


def _not_json(error: Mapping[str, Any]) -> dict[str, str]:
    """A body that is not JSON: where it breaks and what the parser expected there (its
    location is the character's offset, which as a field name read "1: JSON decode error")."""
    location = error.get("loc", ())
    offset = location[-1] if len(location) > 1 and isinstance(location[-1], int) else None
    at_en = "" if offset is None else f" at character {offset}"
    at_es = "" if offset is None else f" en el carácter {offset}"
    detail = str((error.get("ctx") or {}).get("error", "")).strip()
    why = f" ({detail})" if detail else ""
    return {
        "field": "body",
        "en": f"The body is not valid JSON{at_en}{why}. Send a JSON object.",
        "es": f"El cuerpo no es JSON válido{at_es}{why}. Envíe un objeto JSON.",
    }


async def http_error_handler(_request: Request, exc: StarletteHTTPException) -> Response:
    """Exception handler: Starlette's own refusals (unknown path, wrong method...)."""
    if exc.status_code == 400:
        # A body that does not parse (bad JSON, bad multipart) is invalid input like any other.
        return error_response(422, "invalid_input", f"Invalid request: {exc.detail}.")
    return error_response(exc.status_code, "http_error", str(exc.detail))


async def unexpected_error_handler(_request: Request, exc: Exception) -> Response:
    """Exception handler: a bug; logged with its traceback, answered without details."""
    log.error("unexpected error", exc_info=exc)
    message = "Internal error in KyberCore; the server log has details."
    return error_response(500, "internal", message)
