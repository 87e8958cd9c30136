"""The one place where KyberCore's errors become HTTP statuses and error codes."""

from __future__ import annotations

from kybercore.errors import (
    ActionRejected,
    ConfigError,
    InvalidInput,
    KlippyNotReady,
    KyberCoreError,
    MoonrakerRpcError,
    PrinterAuthFailed,
    PrinterTimeout,
    PrinterUnreachable,
    UnknownPrinter,
)

# Most specific first: PrinterTimeout is a PrinterUnreachable.
_STATUSES: tuple[tuple[type[KyberCoreError], int, str], ...] = (
    (UnknownPrinter, 404, "unknown_printer"),
    (ActionRejected, 409, "rejected"),
    (KlippyNotReady, 409, "klippy_not_ready"),
    (InvalidInput, 422, "invalid_input"),
    (PrinterAuthFailed, 502, "printer_auth_failed"),
    (MoonrakerRpcError, 502, "moonraker_error"),
    (PrinterTimeout, 504, "printer_timeout"),
    (PrinterUnreachable, 503, "printer_unreachable"),
    (ConfigError, 500, "config_error"),
)


def error_status(exc: KyberCoreError) -> tuple[int, str]:
    """HTTP status and a stable error code for ``exc``."""
    if isinstance(exc, MoonrakerRpcError) and exc.code == 404:
        return 404, "not_found"  # a file or object the printer does not have
    for kind, status, code in _STATUSES:
        if isinstance(exc, kind):
            if isinstance(exc, ActionRejected):
                return status, exc.code
            return status, code
    return 500, "error"
