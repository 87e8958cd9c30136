"""KyberCore's exceptions, named for what the caller should do next.

::

    KyberCoreError                    anything KyberCore raises on purpose
    ├── PrinterError                  one printer could not do what was asked
    │   ├── PrinterUnreachable        network or Moonraker down: retry later
    │   │   ├── PrinterTimeout        it did not answer in time: retry later
    │   │   │   └── OutcomeUnknown    sent, no answer: check the printer before retrying
    │   │   ├── OwnerMoving           its process is changing (NATS): retry in seconds
    │   │   └── TransferFailed        a file did not cross NATS: nothing reached it, resend
    │   │       └── UploadCorrupted   the copy that crossed is not the file sent: resend
    │   ├── PrinterAuthFailed         Moonraker refused the API key: fix credentials
    │   ├── KlippyNotReady            Moonraker is up, Klippy is not: wait
    │   └── MoonrakerRpcError         Moonraker refused this one call
    ├── UnknownPrinter                no printer with that id: check the id
    ├── ChannelNotFound               no notification channel with that id: check the id
    ├── FileNotFound                  no such file (on a printer or here): check the name
    ├── ActionRejected                the action is not valid now (state, limits)
    ├── InvalidInput                  the request itself is malformed
    ├── AccessDenied                  who are you (unauthenticated) or not allowed (forbidden)
    ├── BrokerUnavailable             NATS did not answer (distributed mode): check it, retry
    ├── DatabaseUnavailable           the database did not answer: check it, retry
    ├── ConfigError                   printers.json, tokens.json or an option is unusable
    └── LaunchError                   a process or port KyberCore needs could not be had

Every error has a stable machine ``code`` and a message that says what happened and what
to do, in words meant for any caller: no HTTP status, no CLI option. The HTTP mapping
lives in :mod:`kybercore.api.errors` and nowhere else.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import ClassVar, Final, Literal


class KyberCoreError(Exception):
    """Base of every error KyberCore raises on purpose."""

    code: str = "error"
    """A stable machine-readable name for what went wrong."""

    def __init__(self, message: str, *, reasons: Iterable[dict[str, str]] = ()) -> None:
        super().__init__(message)
        self.message = message
        self.reasons: tuple[dict[str, str], ...] = tuple(reasons)
        """Validation reasons behind the error, when there are any (code, level, en, es)."""


class PrinterError(KyberCoreError):
    """A printer could not do what was asked."""

    code = "printer_error"

    def __init__(
        self,
        message: str,
        *,
        printer: str | None = None,
        reasons: Iterable[dict[str, str]] = (),
    ) -> None:
        super().__init__(f"{printer}: {message}" if printer else message, reasons=reasons)
        self.printer = printer


class PrinterUnreachable(PrinterError):
    """The printer's Moonraker cannot be reached now; retry later."""

    code = "printer_unreachable"


class PrinterTimeout(PrinterUnreachable):
    """The printer did not answer within the time allowed; retry later."""

    code = "printer_timeout"


class OwnerMoving(PrinterUnreachable):
    """No KyberCore process holds the printer right now (a worker died or the printers are
    being rebalanced): nothing was sent; retry in a few seconds."""

    code = "owner_moving"


class OutcomeUnknown(PrinterTimeout):
    """The request reached the printer's owner but no answer came back: it may have run.
    Never retried on its own; look at the printer before sending it again."""

    code = "outcome_unknown"


class TransferFailed(PrinterUnreachable):
    """A file could not be carried between KyberCore's processes on NATS (the broker away,
    the copy gone): nothing reached the printer; send it again."""

    code = "transfer_failed"


class UploadCorrupted(TransferFailed):
    """The copy of an uploaded file that reached the printer's KyberCore worker is not the
    file that was sent (its size or sha256 differ): nothing was uploaded or started."""

    code = "upload_corrupted"


class PrinterAuthFailed(PrinterError):
    """Moonraker refused our credentials; fix the printer's API key."""

    code = "printer_auth_failed"


class KlippyNotReady(PrinterError):
    """Moonraker answers but Klippy is not ready; wait or restart the firmware."""

    code = "klippy_not_ready"

    def __init__(self, message: str, *, printer: str | None = None, state: str = "") -> None:
        super().__init__(message, printer=printer)
        self.state = state


class MoonrakerRpcError(PrinterError):
    """Moonraker answered this call with an error."""

    code = "moonraker_error"

    def __init__(self, code: int, message: str, *, printer: str | None = None) -> None:
        super().__init__(f"Moonraker refused the request ({code}): {message}", printer=printer)
        self.rpc_code = code
        self.detail = message


class UnknownPrinter(KyberCoreError):
    """No printer with that id exists."""

    code = "unknown_printer"

    def __init__(self, printer_id: str) -> None:
        super().__init__(
            f"No printer with id '{shorten(printer_id)}'. List the fleet with GET /api/printers "
            "or `kybercore printers list`."
        )
        self.printer_id = printer_id


class ChannelNotFound(KyberCoreError):
    """No notification channel with that id exists."""

    code = "channel_not_found"

    def __init__(self, channel_id: int) -> None:
        super().__init__(
            f"No notification channel with id {channel_id}. List the channels with "
            "GET /api/notifications/channels or `kybercore notify channels`."
        )
        self.channel_id = channel_id


class FileNotFound(KyberCoreError):
    """A file that is not there: on a printer, or one KyberCore was asked to read."""

    code = "not_found"


class ActionRejected(KyberCoreError):
    """The action is not allowed in the printer's current state or limits."""

    def __init__(
        self, message: str, *, code: str = "rejected", reasons: Iterable[dict[str, str]] = ()
    ) -> None:
        super().__init__(message, reasons=reasons)
        self.code = code


class InvalidInput(KyberCoreError):
    """The request is malformed: fix the input and send it again."""

    code = "invalid_input"


class AccessDenied(KyberCoreError):
    """The caller is not known (``unauthorized``) or may not do this (``forbidden``)."""

    Kind = Literal["unauthorized", "forbidden"]
    KINDS: ClassVar[tuple[str, ...]] = ("unauthorized", "forbidden")

    def __init__(self, message: str, *, code: AccessDenied.Kind) -> None:
        super().__init__(message)
        self.code = code


class BrokerUnavailable(KyberCoreError):
    """The NATS broker KyberCore's processes share did not answer (the distributed mode):
    what needed it (the printer registry) was not read, or a change to it may or may not
    have been made; check that nats-server runs and is reachable, then retry."""

    code = "broker_unavailable"


class DatabaseUnavailable(KyberCoreError):
    """KyberCore's database (the queue, the ledger) could not be reached or its connection
    was lost: what needed it was not read, or a change may or may not have been made; check
    that the database runs and is reachable, then retry."""

    code = "database_unavailable"


class ConfigError(KyberCoreError):
    """A configuration file or option cannot be used as it is."""

    code = "config_error"


class LaunchError(KyberCoreError):
    """Something KyberCore starts could not start: a port in use, an install, a process."""

    code = "launch_error"


_USE_SERVE: Final = "use `kybercore serve`, or the printer's own Mainsail or Fluidd, for this"


def not_on_front(what: str, instead: str = _USE_SERVE) -> ActionRejected:
    """The refusal of a KyberCore front (on NATS) for what it does not do yet: ``what``
    starts the sentence ("The job queue", "Notifications"), ``instead`` ends it with what to
    use ("use ...")."""
    return ActionRejected(
        f"{what} is not available on a KyberCore front yet (the distributed mode): {instead}.",
        code="not_on_front",
    )


def shorten(text: str, limit: int = 100) -> str:
    """``text`` cut to ``limit`` characters for a message (ids and paths come from users)."""
    return text if len(text) <= limit else text[:limit] + "…"
