"""Moonraker over HTTP: the shared client, its timeouts, and what an answer means.

A failed request becomes a typed :mod:`kybercore.errors` exception whose message says what
happened and what to do.
"""

from __future__ import annotations

from typing import Any, Final

import httpx
import orjson

from kybercore.errors import (
    KlippyNotReady,
    KyberCoreError,
    MoonrakerRpcError,
    PrinterAuthFailed,
)
from kybercore.moonraker.refusals import auth_failure, http_reason, refusal

REQUEST_TIMEOUT: Final = httpx.Timeout(10.0, connect=3.0)
# `/printer/gcode/script` answers only when the G-code has run: M109 or G28 take minutes.
GCODE_TIMEOUT: Final = httpx.Timeout(600.0, connect=3.0)
UPLOAD_TIMEOUT: Final = httpx.Timeout(300.0, connect=3.0)
# Pause and cancel wait for the moves already queued (and a G28 in progress) to finish.
ACTION_TIMEOUT: Final = httpx.Timeout(60.0, connect=3.0)


def new_http_client() -> httpx.AsyncClient:
    """The one HTTP client a process shares across all its printers."""
    # trust_env=False: printers live on the LAN; a desktop proxy setting must not apply.
    return httpx.AsyncClient(
        timeout=REQUEST_TIMEOUT,
        trust_env=False,
        limits=httpx.Limits(max_connections=1000, max_keepalive_connections=200),
    )


def json_body(response: httpx.Response, printer: str) -> Any:
    """The JSON body of a Moonraker answer; a typed error when it is not JSON."""
    try:
        return orjson.loads(response.content)
    except orjson.JSONDecodeError:
        raise MoonrakerRpcError(
            response.status_code,
            f"{response.request.url.host} answered {response.request.url.path} with something "
            "that is not JSON. Is the URL really a Moonraker server?",
            printer=printer,
        ) from None


def http_error(response: httpx.Response, path: str, printer: str) -> KyberCoreError:
    """The typed error for a Moonraker answer that is not a success."""
    status = response.status_code
    try:
        error = orjson.loads(response.content).get("error", {})
    except (orjson.JSONDecodeError, AttributeError):
        error = response.text[:200]
    if isinstance(error, dict):
        message = http_reason(
            status, str(error.get("message", "")), str(error.get("traceback") or "")
        )
    else:
        message = str(error)
    if auth_failure(status, message):
        return PrinterAuthFailed(
            f"Moonraker refused the request (HTTP {status}): the API key is missing or wrong. "
            "Set the printer's api_key to the key from Moonraker's /access/api_key.",
            printer=printer,
        )
    klippy_away = status != 400 and "klippy" in message.lower()  # a 400 is Klipper's refusal
    if path.startswith("/printer/") and (status == 404 or klippy_away):
        # Klippy registers the /printer/* endpoints, so they 404 until it first connects;
        # once known, they answer 503 "Klippy Host not connected" while it is away.
        return KlippyNotReady(
            "Klippy is not connected to Moonraker yet. Wait for it to start, or check "
            "klippy.log on the printer.",
            printer=printer,
        )
    error = MoonrakerRpcError(status, message or response.reason_phrase, printer=printer)
    return refusal(error, path) or error
