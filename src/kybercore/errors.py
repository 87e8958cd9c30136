"""KyberCore's exceptions, named for what the caller should do next.

::

    KyberCoreError                    anything KyberCore raises on purpose
    ├── PrinterError                  one printer could not do what was asked
    │   ├── PrinterUnreachable        network or Moonraker down: retry later
    │   │   └── PrinterTimeout        it did not answer in time: retry later
    │   ├── PrinterAuthFailed         Moonraker refused the API key: fix credentials
    │   ├── KlippyNotReady            Moonraker is up, Klippy is not: wait
    │   └── MoonrakerRpcError         Moonraker refused this one call
    ├── UnknownPrinter                no printer with that id: check the id
    ├── ActionRejected                the action is not valid now (state, limits)
    ├── InvalidInput                  the request itself is malformed
    └── ConfigError                   printers.json (or other config) is unusable

Every message says what happened and what to do about it; the HTTP mapping lives in
``fleet_controller`` and nowhere else.
"""

from __future__ import annotations


class KyberCoreError(Exception):
    """Base of every error KyberCore raises on purpose."""

    reasons: tuple[dict[str, str], ...] = ()
    """Validation reasons behind the error, when there are any (code, level, en, es)."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class PrinterError(KyberCoreError):
    """A printer could not do what was asked."""

    def __init__(self, message: str, *, printer: str | None = None) -> None:
        super().__init__(f"{printer}: {message}" if printer else message)
        self.printer = printer


class PrinterUnreachable(PrinterError):
    """The printer's Moonraker cannot be reached now; retry later."""


class PrinterTimeout(PrinterUnreachable):
    """The printer did not answer within the time allowed; retry later."""


class PrinterAuthFailed(PrinterError):
    """Moonraker refused our credentials; fix the printer's API key."""


class KlippyNotReady(PrinterError):
    """Moonraker answers but Klippy is not ready; wait or restart the firmware."""

    def __init__(self, message: str, *, printer: str | None = None, state: str = "") -> None:
        super().__init__(message, printer=printer)
        self.state = state


class MoonrakerRpcError(PrinterError):
    """Moonraker answered this call with an error."""

    def __init__(self, code: int, message: str, *, printer: str | None = None) -> None:
        super().__init__(f"Moonraker refused the request ({code}): {message}", printer=printer)
        self.code = code
        self.detail = message


class UnknownPrinter(KyberCoreError):
    """No printer with that id exists."""

    def __init__(self, printer_id: str) -> None:
        shown = printer_id if len(printer_id) <= 100 else printer_id[:100] + "…"
        super().__init__(
            f"No printer with id '{shown}'. List the fleet with GET /api/printers "
            "or `kybercore printers list`."
        )
        self.printer_id = printer_id


class ActionRejected(KyberCoreError):
    """The action is not allowed in the printer's current state or limits."""

    def __init__(self, message: str, *, code: str = "rejected") -> None:
        super().__init__(message)
        self.code = code


class InvalidInput(KyberCoreError):
    """The request is malformed: fix the input and send it again."""


class ConfigError(KyberCoreError):
    """A configuration file cannot be used as it is."""
