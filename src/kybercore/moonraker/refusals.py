"""What Moonraker's error answers mean: the user's request refused, or Moonraker failing.

A 400 from Moonraker (an HTTP status or a JSON-RPC code) is Klipper or Moonraker refusing
this one request: a file that is not there, a move before homing, a temperature out of
range, anything at all while Klippy is shut down. Those become :class:`FileNotFound`,
:class:`ActionRejected`, :class:`InvalidInput` or :class:`KlippyNotReady`, in Klipper's own
words; :class:`MoonrakerRpcError` is left for Moonraker itself misbehaving.

Moonraker 0.11 sends Klipper's reason whole over the WebSocket, but over HTTP a reason that
spans lines arrives as a bare ``"Unknown"`` (or ``"Bad Request"``), the words only in the
``traceback`` it sends along: :func:`http_reason` takes them from there.
"""

from __future__ import annotations

import re
from http import HTTPStatus
from typing import Any, Final

from kybercore.errors import (
    ActionRejected,
    FileNotFound,
    InvalidInput,
    KlippyNotReady,
    KyberCoreError,
    MoonrakerRpcError,
    PrinterAuthFailed,
    PrinterError,
)

_MISSING_FILE: Final = re.compile(
    r"invalid file path|unable to open file|does not exist|no such file|file not found", re.I
)
# Klippy is shut down or in error: every command but a restart is refused.
_NOT_READY: Final = re.compile(
    r"printer is shutdown|shutdown due to|error configuring printer|klipper state: not ready"
    r"|printer is not ready",
    re.I,
)
# Klipper's words for a parameter it cannot take (gcode.py, heaters.py, toolhead.py).
_BAD_VALUE: Final = re.compile(
    r"out of range|is not valid for|no data for argument|^error on '|unable to parse"
    r"|must (?:be|have) (?:above|below|minimum|maximum)|invalid (?:argument|parameter)",
    re.I,
)
# Moonraker's 403s for a file the printer is using; its auth failures are 401s.
_IN_USE: Final = re.compile(r"currently in use|file is loaded", re.I)
# The last exception line of the traceback Moonraker sends: "HTTPError: HTTP 400: ...".
_TRACEBACK_REASON: Final = re.compile(r"HTTPError: HTTP \d{3}: ")


def auth_failure(code: int, text: str) -> bool:
    """Whether Moonraker's error ``code`` and ``text`` mean our credentials were refused."""
    lowered = text.lower()
    if code == 403:
        return not _IN_USE.search(text)
    # Moonraker answers a bad key in `identify` with -32602 "Invalid API Key".
    return code == 401 or "api key" in lowered or "unauthorized" in lowered


def rpc_error(error: Any, method: str, printer: str) -> PrinterError:
    """The typed error for a JSON-RPC ``error`` member (any shape a peer may send)."""
    raw_code = error.get("code") if isinstance(error, dict) else None
    code = raw_code if isinstance(raw_code, int) and not isinstance(raw_code, bool) else -1
    text = str(error.get("message", error)) if isinstance(error, dict) else str(error)
    if auth_failure(code, text):
        return PrinterAuthFailed(
            f"Moonraker refused the API key ({text}). Fix the printer's api_key.", printer=printer
        )
    # Klippy registers the printer.* methods, so they are "not found" until it connects;
    # once known, they answer 503 "Klippy Host not connected" while it is away.
    if method.startswith("printer.") and (
        code == -32601 or (code == 503 and "klippy" in text.lower())
    ):
        return KlippyNotReady(
            "Klippy is not connected to Moonraker; wait for it or restart the firmware.",
            printer=printer,
        )
    return MoonrakerRpcError(code, text, printer=printer)


def http_reason(status: int, message: str, traceback: str) -> str:
    """Moonraker's reason for an HTTP error: its ``message``, or, when that is bare, the
    reason on the traceback's last ``HTTP 400:`` line (or its last ``!!`` line)."""
    bare = message.strip() in ("", "Unknown", _phrase(status))
    if not bare or not traceback:
        return message
    found = list(_TRACEBACK_REASON.finditer(traceback))
    if found:
        reason = traceback[found[-1].end() :].strip()
        # tornado's HTTPError(400, "why") reads "Bad Request (why)".
        wrapped = f"{_phrase(status)} ("
        if reason.startswith(wrapped) and reason.endswith(")"):
            reason = reason[len(wrapped) : -1]
        return reason or message
    marked = [line for line in traceback.splitlines() if line.lstrip().startswith("!!")]
    return marked[-1] if marked else message


def refusal(error: MoonrakerRpcError, where: str) -> KyberCoreError | None:
    """What Moonraker's ``error`` to a request at ``where`` (an HTTP path or a JSON-RPC
    method) means for the caller, or ``None`` when it stays a Moonraker error."""
    words = klipper_words(error.detail)
    printer = error.printer
    prefix = f"{printer}: " if printer else ""
    klippy = where.startswith(("/printer/", "printer."))
    if error.rpc_code == 403 and _IN_USE.search(words):
        message = f"{prefix}the printer is using this file: {words}."
        return ActionRejected(message, code="file_in_use")
    if error.rpc_code == 405:
        return InvalidInput(f"{prefix}Moonraker does not allow this: {words}.")
    if error.rpc_code != 400:
        return None
    if _MISSING_FILE.search(words):
        return FileNotFound(
            f"{prefix}the printer has no such file ({words}). Check the name in its file list."
        )
    if klippy and _NOT_READY.search(words):
        state = "error" if "error configuring" in words.lower() else "shutdown"
        return KlippyNotReady(f"Klipper refused it: {words}", printer=printer, state=state)
    if _BAD_VALUE.search(words):
        who = "Klipper" if klippy else "Moonraker"
        return InvalidInput(f"{prefix}{who} refused the values: {words}")
    if klippy:
        return ActionRejected(f"{prefix}Klipper refused it: {words}", code="klipper_refused")
    return InvalidInput(f"{prefix}Moonraker refused the request: {words}")


def klipper_words(text: str) -> str:
    """Klipper's reason on one line: its ``!!`` marks dropped, its wrapped lines joined."""
    lines = [line.strip().removeprefix("!!").strip() for line in text.splitlines()]
    joined = ""
    for line in filter(None, lines):
        if not joined:
            joined = line
        elif joined[-1] in ".!?:;," or not line[0].isupper():
            joined += " " + line
        else:  # a new sentence Klipper did not end with a full stop
            joined += ". " + line
    return joined


def _phrase(status: int) -> str:
    try:
        return HTTPStatus(status).phrase
    except ValueError:
        return ""
