"""The notifications API's request and answer models (``/api/notifications/...``).

A request is checked here field by field, so a refusal names the field and says what to
write instead (a 422 in the usual envelope). The pure rules they turn into are
:class:`~kybercore.notify.rules.ChannelRules` and
:class:`~kybercore.notify.models.NoiseSettings`.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated, Final, Literal
from urllib.parse import urlsplit

from pydantic import BaseModel, ConfigDict, Field, field_validator

from kybercore.notify.models import (
    DEFAULT_EVENTS,
    EVENT_KINDS,
    UNREPORTED_GRACE_S,
    EventKind,
    NoiseSettings,
    Severity,
)
from kybercore.notify.rules import ChannelRules, QuietHours, clock

MAX_TARGET: Final = 2000
MAX_LIST: Final = 200
WEEK: Final = 7 * 86400.0

Name = Annotated[str, Field(min_length=1, max_length=100)]
Item = Annotated[str, Field(min_length=1, max_length=200)]
Secret = Annotated[
    str,
    Field(
        min_length=16,
        max_length=200,
        description="The webhook's HMAC-SHA256 key (write-only: never shown again).",
    ),
]

KIND_LABELS: Final[dict[EventKind, tuple[str, str]]] = {
    "print_started": ("Print started", "Impresión iniciada"),
    "print_completed": ("Print completed", "Impresión terminada"),
    "print_failed": ("Print failed", "Impresión fallida"),
    "print_cancelled": ("Print cancelled", "Impresión cancelada"),
    "print_paused": ("Print paused", "Impresión en pausa"),
    "first_layer_done": ("First layer done", "Primera capa terminada"),
    "printer_offline": ("Printer offline", "Impresora desconectada"),
    "printer_recovered": ("Printer recovered", "Impresora recuperada"),
    "klippy_shutdown": ("Klipper shutdown", "Apagado de Klipper"),
    "klippy_error": ("Klipper error", "Error de Klipper"),
    "plate_waiting": ("Plate waiting to be cleared", "Placa esperando a ser retirada"),
    "job_blocked": ("Queue job blocked", "Trabajo de la cola bloqueado"),
    "storm_offline": ("Many printers offline", "Muchas impresoras desconectadas"),
    "printer_unreported": (
        "No KyberCore worker reports a printer",
        "Ningún worker de KyberCore informa de una impresora",
    ),
    "test": ("Test message", "Mensaje de prueba"),
}
"""How the dashboard and the CLI name each event kind."""


class QuietHoursIn(BaseModel):
    """Hours (server local time) when only critical events, or none, are sent."""

    model_config = ConfigDict(extra="forbid")

    start: str = Field(description="HH:MM, 24-hour clock, server local time.", examples=["22:00"])
    end: str = Field(description="HH:MM; before start: the quiet hours span midnight.")
    allow_critical: bool = Field(
        default=True, description="Critical events (a failed print, a printer lost) still go."
    )

    @field_validator("start", "end")
    @classmethod
    def _clock(cls, value: str) -> str:
        clock(value)  # ValueError: "'7pm' is not a time of day as HH:MM, e.g. 22:30"
        return value


class RulesIn(BaseModel):
    """Which events a channel gets, about which printers, and who may change it."""

    model_config = ConfigDict(extra="forbid")

    events: list[EventKind] = Field(
        default_factory=lambda: [k for k in EVENT_KINDS if k in DEFAULT_EVENTS],
        max_length=len(EVENT_KINDS),
        description="Event kinds to send (GET /api/notifications/kinds lists them).",
    )
    printers: list[Item] = Field(
        default_factory=list, max_length=MAX_LIST, description="Printer ids; empty: all."
    )
    locations: list[Item] = Field(
        default_factory=list, max_length=MAX_LIST, description="Locations; empty: all."
    )
    tags: list[Item] = Field(
        default_factory=list,
        max_length=MAX_LIST,
        description="The printer must carry one of these tags; empty: any.",
    )
    quiet_hours: QuietHoursIn | None = None
    language: Literal["en", "es"] = "en"
    attach_snapshot: bool = Field(
        default=True, description="Attach a webcam snapshot when the printer has a webcam."
    )
    min_role: Literal["operator", "admin"] = Field(
        default="admin", description="The role needed to change or remove this channel."
    )

    def rules(self) -> ChannelRules:
        """The pure rules these fields describe."""
        quiet = self.quiet_hours
        return ChannelRules(
            events=frozenset(self.events),
            printers=tuple(self.printers),
            locations=tuple(self.locations),
            tags=tuple(self.tags),
            quiet_hours=QuietHours(quiet.start, quiet.end, quiet.allow_critical) if quiet else None,
            language=self.language,
            attach_snapshot=self.attach_snapshot,
            min_role=self.min_role,
        )


class ChannelCreate(BaseModel):
    """A new channel: a webhook URL, or an Apprise URL (ntfy, Telegram, Discord, Slack,
    e-mail, Pushover, Matrix… see Apprise's documentation)."""

    model_config = ConfigDict(extra="forbid")

    name: Name
    kind: Literal["webhook", "apprise"]
    target: str = Field(
        min_length=1,
        max_length=MAX_TARGET,
        description="webhook: an http(s) URL; apprise: an Apprise URL such as ntfys://ntfy.sh/topic.",
    )
    secret: Secret | None = Field(
        default=None,
        description="webhook only: the signing key; generated when omitted. The answer "
        "shows it once.",
    )
    rules: RulesIn = Field(default_factory=RulesIn)
    enabled: bool = True


class ChannelPatch(BaseModel):
    """Changes to a channel; omitted fields stay as they are."""

    model_config = ConfigDict(extra="forbid")

    name: Name | None = None
    target: str | None = Field(default=None, min_length=1, max_length=MAX_TARGET)
    secret: Secret | None = Field(default=None, description="webhook only: a new signing key.")
    rules: RulesIn | None = None
    enabled: bool | None = None


class QuietHoursOut(BaseModel):
    start: str
    end: str
    allow_critical: bool


class RulesOut(BaseModel):
    events: list[str]
    printers: list[str]
    locations: list[str]
    tags: list[str]
    quiet_hours: QuietHoursOut | None
    language: str
    attach_snapshot: bool
    min_role: str


class ChannelOut(BaseModel):
    """A channel as shown: its target masked, its secret never."""

    id: int
    name: str
    kind: str
    target: str = Field(description="Masked: an Apprise URL's credentials and a webhook "
                        "URL's user info and query are not shown.")  # fmt: skip
    has_secret: bool
    rules: RulesOut
    enabled: bool
    created_at: str
    created_by: str
    updated_at: str | None = None
    updated_by: str | None = None


class ChannelCreated(ChannelOut):
    """The answer to a create: the channel, and its webhook secret this once."""

    secret: str | None = Field(
        default=None, description="The webhook's signing key: shown only now."
    )


class DeliveryOut(BaseModel):
    """One event for one channel, and how sending it went."""

    id: int
    event_id: str
    channel_id: int
    channel_name: str
    kind: str
    printer_id: str | None
    status: Literal["pending", "delivered", "failed", "quiet_hours"]
    attempts: int
    next_at: str | None = Field(description="When it is tried again (pending only).")
    last_error: str
    response_code: int | None
    created_at: str
    delivered_at: str | None
    title: str = Field(description="The message's title in the channel's language.")


class SettingsBody(BaseModel):
    """The fleet-wide noise control."""

    model_config = ConfigDict(extra="forbid")

    cooldown_s: float = Field(ge=0, le=WEEK, description="Per printer and event kind.")
    fold_window_s: float = Field(
        ge=0, le=600, description="Offline and plate events are held this long to fold them."
    )
    storm_threshold: int = Field(
        ge=1, le=100_000, description="More printers of one location offline: one message."
    )
    offline_grace_s: float = Field(
        ge=0, le=WEEK, description="An idle printer offline this long alerts too; 0: never."
    )
    plate_wait_s: float = Field(ge=0, le=WEEK, description="A plate waiting longer alerts.")
    job_blocked_s: float = Field(ge=0, le=WEEK, description="A job stuck longer alerts.")
    unreported_grace_s: float = Field(
        default=UNREPORTED_GRACE_S,
        ge=0,
        le=WEEK,
        description="On NATS: a printer no KyberCore worker reports this long alerts; 0: never.",
    )

    @classmethod
    def of(cls, settings: NoiseSettings) -> SettingsBody:
        """The API's form of ``settings``."""
        return cls(**asdict(settings))

    def settings(self) -> NoiseSettings:
        """The pure settings."""
        return NoiseSettings(**self.model_dump())


class KindOut(BaseModel):
    """An event kind, its labels and severity."""

    kind: str
    severity: Severity
    default: bool = Field(description="Selected for a new channel.")
    en: str
    es: str


def webhook_url_problem(url: str) -> str | None:
    """Why ``url`` is no webhook address (a message), or None."""
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 -- raises on a port that is not a number
    except ValueError:
        return "is not a URL: write it as http(s)://host[:port]/path"
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return "must be an http:// or https:// URL with a host, e.g. https://hooks.example/kc"
    return None
