"""What a Moonraker session tells its owner: its connection, Klippy's state, the status of
the subscribed objects, and every other notification. Plain frozen dataclasses, so the
fleet service and the tests match on them without any I/O."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from kybercore.moonraker.objects import Status


@dataclass(frozen=True, slots=True)
class ConnectionChanged:
    """The session's link to Moonraker changed: ``connecting|online|offline|auth_failed``."""

    connection: str
    detail: str = ""


@dataclass(frozen=True, slots=True)
class KlippyChanged:
    """Klippy's state as Moonraker reports it: ``ready|startup|shutdown|error|disconnected``."""

    state: str
    message: str = ""


@dataclass(frozen=True, slots=True)
class StatusSnapshot:
    """The full state of the subscribed objects, sent after every (re)subscription."""

    status: Status


@dataclass(frozen=True, slots=True)
class StatusDelta:
    """Only the fields that changed (``notify_status_update``)."""

    delta: Status
    eventtime: float


@dataclass(frozen=True, slots=True)
class Notification:
    """Any other Moonraker notification (gcode responses, history, file list, ...)."""

    method: str
    params: list[Any]


SessionEvent = ConnectionChanged | KlippyChanged | StatusSnapshot | StatusDelta | Notification
EventCallback = Callable[[SessionEvent], None]
