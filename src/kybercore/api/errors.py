"""The one place where errors become HTTP answers: the status map and the error envelope.

Every error KyberCore answers has the same shape::

    {"error": {"code": "...", "message": "...", "reasons": [...], "fields": [...]?}}

``code`` is the error's stable name (:attr:`KyberCoreError.code`), ``message`` says what
to do, ``reasons`` are validation reasons (en/es) and ``fields`` per-field problems of a
request that did not validate.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Final

import orjson
from fastapi.responses import Response

from kybercore.errors import (
    AccessDenied,
    ActionRejected,
    ConfigError,
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

# Most specific first: PrinterTimeout is a PrinterUnreachable.
_STATUSES: Final[tuple[tuple[type[KyberCoreError], int], ...]] = (
    (UnknownPrinter, 404),
    (FileNotFound, 404),
    (ActionRejected, 409),
    (KlippyNotReady, 409),
    (InvalidInput, 422),
    (PrinterAuthFailed, 502),
    (MoonrakerRpcError, 502),
    (PrinterTimeout, 504),
    (PrinterUnreachable, 503),
    (ConfigError, 500),
    (LaunchError, 500),
)
_ACCESS: Final = {"unauthorized": 401, "forbidden": 403}


def error_status(exc: KyberCoreError) -> tuple[int, str]:
    """HTTP status and the stable error code for ``exc``."""
    if isinstance(exc, AccessDenied):
        return _ACCESS[exc.code], exc.code
    if isinstance(exc, MoonrakerRpcError) and exc.rpc_code == 404:
        return 404, "not_found"  # a file or object the printer does not have
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
