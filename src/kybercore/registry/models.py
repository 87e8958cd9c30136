"""The models of one printer's configuration, as stored in printers.json and sent over the API.

Pure data and validation, no I/O: :mod:`kybercore.registry.store` reads and writes them.

- :class:`PrinterConfig` is one stored printer, API key included (as a ``SecretStr``).
- :class:`PrinterPublic` is what every response shows: ``api_key_set`` instead of the key.
- :class:`PrinterCreate` and :class:`PrinterUpdate` are the inputs of the API and the CLI;
  ``PrinterUpdate`` has PATCH semantics (omitted fields keep their value).
"""

from __future__ import annotations

import re
import unicodedata
from typing import Annotated, Any, Self
from urllib.parse import urlsplit

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    SecretStr,
    StringConstraints,
    model_validator,
)
from pydantic_core import PydanticCustomError

SLUG_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,63}$"
SITE_PATTERN = r"^(?:[a-z0-9][a-z0-9_-]{0,31})?$"
MAX_URL_LENGTH = 2048
URL_PATTERN = (
    r"^(?:[Hh][Tt][Tt][Pp][Ss]?://)?"
    r"(?:\[[0-9A-Fa-f:.]+\]|[^\s\x00-\x1f/?#@:\[\]]+)(?::[0-9]*)?"
    r"/?$"
)
"""What :func:`_check_url` accepts, for the OpenAPI schema (a port's range and an IPv6
address's validity aside): http(s) (``http://`` when left out), a host or [IPv6], an
optional port; no path, credentials, query, fragment, spaces or control characters."""
API_KEY_PATTERN = r"^[!-~]*$"
"""Printable ASCII without spaces (it travels in a header); empty means no key."""


SPANISH = "_es"
"""The context key of a validation error's Spanish text (read by the API's 422 answer)."""


def _invalid(english: str, spanish: str) -> PydanticCustomError:
    """A validation error in both of the dashboard's languages (the API's 422 carries both)."""
    # pydantic fills "{name}" from the context in the template: a key no message holds.
    return PydanticCustomError("invalid_value", english, {SPANISH: spanish})


def _check_url(url: str) -> str:
    """Accept an http(s) URL with a host and nothing secret or variable; normalize it."""
    if any(c.isspace() or ord(c) < 32 for c in url):
        raise _invalid(
            "the URL must not contain spaces or control characters",
            "la URL no puede contener espacios ni caracteres de control",
        )
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 -- property access validates the port (raises ValueError)
    except ValueError as exc:
        raise _invalid(f"not a valid URL ({exc})", f"la URL no es válida ({exc})") from None
    scheme = parts.scheme.lower()
    if scheme not in ("http", "https"):
        if parts.scheme:
            raise _invalid(
                f"the URL must start with http:// or https://, not '{parts.scheme}:'",
                f"la URL debe empezar por http:// o https://, no por '{parts.scheme}:'",
            )
        raise _invalid(
            "the URL must start with http:// or https://, e.g. http://192.168.1.50:7125",
            "la URL debe empezar por http:// o https://, p. ej. http://192.168.1.50:7125",
        )
    if "@" in parts.netloc:
        raise _invalid(
            "the URL must not contain credentials; set the printer's api_key instead",
            "la URL no puede llevar credenciales; indica la clave de API de la impresora",
        )
    if not parts.hostname:
        raise _invalid(
            "the URL has no host, e.g. http://192.168.1.50:7125",
            "a la URL le falta el host, p. ej. http://192.168.1.50:7125",
        )
    # Brackets belong around an IPv6 address only ("http://[::1]:7125"); urlsplit lets
    # "]a[::1" through as a host.
    if ("[" in parts.netloc or "]" in parts.netloc) and not re.fullmatch(
        r"\[[0-9A-Fa-f:.]+\](:[0-9]*)?", parts.netloc
    ):
        raise _invalid(
            "not a valid URL (brackets only around an IPv6 address)",
            "la URL no es válida (los corchetes solo rodean una dirección IPv6)",
        )
    if parts.query or parts.fragment or url.endswith(("?", "#")):
        raise _invalid(
            "the URL must not have a query string or fragment",
            "la URL no puede llevar parámetros (?) ni fragmento (#)",
        )
    # Moonraker answers at the root of its host and port (/server/info, /websocket): a
    # path is a pasted page address ("/server/info", Mainsail's "/#/"), never a prefix.
    if parts.path not in ("", "/"):
        raise _invalid(
            f"the URL must be Moonraker's address only, without a path: remove "
            f"'{parts.path}', e.g. http://192.168.1.50:7125",
            f"la URL debe ser solo la dirección de Moonraker, sin ruta: quita "
            f"'{parts.path}', p. ej. http://192.168.1.50:7125",
        )
    return f"{scheme}://{parts.netloc.lower()}"


# What people type for a printer: a host or address and maybe a port, nothing else.
_HOST_AND_PORT = re.compile(r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9.-]*)(:[0-9]+)?/?")


def _complete_url(value: object) -> object:
    # "192.168.1.50:7125" or "printer.local" is what people type: Moonraker speaks plain
    # HTTP on a farm's network unless told otherwise. Anything else is judged as given.
    if isinstance(value, str) and _HOST_AND_PORT.fullmatch(value):
        return "http://" + value
    return value


def server_of(url: str) -> tuple[str, str, int]:
    """The (scheme, host, port) a Moonraker URL reaches; its path does not change the server."""
    parts = urlsplit(url)
    port = parts.port or (443 if parts.scheme == "https" else 80)
    return parts.scheme, parts.hostname or "", port


def _dedupe(tags: list[str]) -> list[str]:
    return list(dict.fromkeys(tags))


def _api_key_input(value: object) -> object:
    # "" means "no key" everywhere: in the file, on create, and (as a clear) on update.
    if value == "":
        return None
    # The key goes into an X-Api-Key header: printable ASCII, no spaces.
    if isinstance(value, str) and not all("!" <= c <= "~" for c in value):
        raise _invalid(
            "the API key must be printable ASCII without spaces",
            "la clave de API solo puede tener caracteres ASCII imprimibles, sin espacios",
        )
    return value


Slug = Annotated[str, StringConstraints(pattern=SLUG_PATTERN)]
Site = Annotated[str, StringConstraints(pattern=SITE_PATTERN)]
Url = Annotated[
    str,
    StringConstraints(max_length=MAX_URL_LENGTH),
    BeforeValidator(_complete_url),
    AfterValidator(_check_url),
    Field(json_schema_extra={"pattern": URL_PATTERN, "format": "uri"}),
]
Name = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=100)]
ShortText = Annotated[str, StringConstraints(strip_whitespace=True, max_length=100)]
Notes = Annotated[str, StringConstraints(max_length=2000)]
Tag = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=32)]
Tags = Annotated[list[Tag], Field(max_length=32), AfterValidator(_dedupe)]
ApiKey = Annotated[
    Annotated[
        SecretStr,
        StringConstraints(max_length=256),
        Field(json_schema_extra={"pattern": API_KEY_PATTERN}),
    ]
    | None,
    BeforeValidator(_api_key_input),
]

_DOC = {
    "id": "Stable identifier: lowercase letters, digits, '-' and '_', 1-64 characters, "
    "starting with a letter or digit. Used in URLs; cannot be changed.",
    "name": "Name shown to people, 1-100 characters.",
    "model": "Printer model, e.g. 'Voron 2.4'.",
    "location": "Where the printer is, e.g. 'Room B, shelf 2'.",
    "power_group": "The circuit the printer shares with others, e.g. 'Room B, breaker 3': "
    "the job queue lets only a few printers of one group heat at once. Empty means its "
    "location.",
    "site": "The site (building, town) whose KyberCore workers connect to the printer when "
    "KyberCore runs on NATS (`kybercore ingest --site`): lowercase letters, digits, '-' and "
    "'_', up to 32 characters. Empty: the workers started without --site. One process "
    "(`kybercore serve`) holds every site.",
    "tags": "Short labels (1-32 characters each, at most 32) for grouping; duplicates dropped.",
    "notes": "Free text for the operators, up to 2000 characters.",
    "moonraker_url": "Moonraker's address: http or https, host, optional port "
    "(`192.168.1.50:7125` is completed to `http://192.168.1.50:7125`); no path, "
    "credentials, query or fragment. Stored without trailing slash.",
    "api_key": "Moonraker API key, sent as X-Api-Key. Write-only: never returned.",
    "enabled": "Whether KyberCore connects to this printer.",
    "capabilities": "Limits used to validate actions; missing values are read from "
    "Klippy's configfile.",
}


class _Model(BaseModel):
    # hide_input_in_errors: an error about an api_key must not print the key.
    model_config = ConfigDict(strict=True, extra="forbid", hide_input_in_errors=True)


class BuildVolume(_Model):
    """Printable volume in millimetres."""

    x: float = Field(gt=0, le=10_000, description="Width (X) in mm.")
    y: float = Field(gt=0, le=10_000, description="Depth (Y) in mm.")
    z: float = Field(gt=0, le=10_000, description="Height (Z) in mm.")


class Capabilities(_Model):
    """What the printer can do; every field optional, read from Klippy when missing."""

    build_volume: BuildVolume | None = Field(default=None, description="Build volume in mm.")
    nozzle_diameter: float | None = Field(
        default=None, gt=0, le=5, description="Nozzle diameter in mm, e.g. 0.4."
    )
    material: Tag | None = Field(default=None, description="Loaded filament, e.g. 'PLA'.")
    max_extruder_temp: float | None = Field(
        default=None, gt=0, le=600, description="Highest hotend temperature allowed, in °C."
    )
    max_bed_temp: float | None = Field(
        default=None, gt=0, le=300, description="Highest bed temperature allowed, in °C."
    )


class _PrinterFields(_Model):
    """The fields a stored printer and a new one share (``id`` first, as in the file)."""

    id: Slug = Field(description=_DOC["id"])
    name: Name = Field(description=_DOC["name"])
    model: ShortText = Field(default="", description=_DOC["model"])
    location: ShortText = Field(default="", description=_DOC["location"])
    power_group: ShortText = Field(default="", description=_DOC["power_group"])
    site: Site = Field(default="", description=_DOC["site"])
    tags: Tags = Field(default_factory=list, description=_DOC["tags"])
    notes: Notes = Field(default="", description=_DOC["notes"])
    moonraker_url: Url = Field(description=_DOC["moonraker_url"])
    api_key: ApiKey = Field(default=None, description=_DOC["api_key"])
    enabled: bool = Field(default=True, description=_DOC["enabled"])
    capabilities: Capabilities = Field(
        default_factory=Capabilities, description=_DOC["capabilities"]
    )


class PrinterConfig(_PrinterFields):
    """One printer as stored in printers.json, API key included."""

    def public(self) -> PrinterPublic:
        """The view every API response and CLI listing uses: no API key, only whether one is set."""
        fields = {name: getattr(self, name) for name in PrinterConfig.model_fields}
        del fields["api_key"]
        return PrinterPublic(**fields, api_key_set=self.api_key is not None)

    def to_file_dict(self) -> dict[str, Any]:
        """The JSON object stored in printers.json: every field, the API key in clear."""
        data = self.model_dump(mode="json")
        data["api_key"] = self.api_key.get_secret_value() if self.api_key else None
        return data


class PrinterPublic(_Model):
    """A printer's configuration as shown to clients: the API key is replaced by a flag."""

    id: Slug = Field(description=_DOC["id"])
    name: Name = Field(description=_DOC["name"])
    model: ShortText = Field(description=_DOC["model"])
    location: ShortText = Field(description=_DOC["location"])
    power_group: ShortText = Field(description=_DOC["power_group"])
    site: Site = Field(description=_DOC["site"])
    tags: Tags = Field(description=_DOC["tags"])
    notes: Notes = Field(description=_DOC["notes"])
    moonraker_url: Url = Field(description=_DOC["moonraker_url"])
    api_key_set: bool = Field(description="Whether an API key is stored for this printer.")
    enabled: bool = Field(description=_DOC["enabled"])
    capabilities: Capabilities = Field(description=_DOC["capabilities"])


class PrinterCreate(_PrinterFields):
    """A new printer. Without ``id``, one is derived from ``name``."""

    id: Slug | None = Field(  # type: ignore[assignment]  # optional here, required stored
        default=None, description=_DOC["id"] + " Derived from name if absent."
    )

    def to_config(self, printer_id: str) -> PrinterConfig:
        """The stored printer, under ``printer_id`` (the given id or one derived from the name)."""
        fields = {name: getattr(self, name) for name in PrinterCreate.model_fields}
        return PrinterConfig(**{**fields, "id": printer_id})


class PrinterUpdate(_Model):
    """Changes to a printer (PATCH): omitted fields keep their value.

    ``api_key`` null or "" removes the key. ``capabilities`` is merged field by field: a
    capability given as null is removed, one not given is kept.
    """

    name: Name | None = Field(default=None, description=_DOC["name"])
    model: ShortText | None = Field(default=None, description=_DOC["model"])
    location: ShortText | None = Field(default=None, description=_DOC["location"])
    power_group: ShortText | None = Field(default=None, description=_DOC["power_group"])
    site: Site | None = Field(default=None, description=_DOC["site"])
    tags: Tags | None = Field(default=None, description=_DOC["tags"])
    notes: Notes | None = Field(default=None, description=_DOC["notes"])
    moonraker_url: Url | None = Field(default=None, description=_DOC["moonraker_url"])
    api_key: ApiKey = Field(default=None, description=_DOC["api_key"] + " null or '' removes it.")
    enabled: bool | None = Field(default=None, description=_DOC["enabled"])
    capabilities: Capabilities | None = Field(
        default=None, description=_DOC["capabilities"] + " Merged field by field."
    )

    @model_validator(mode="after")
    def _only_api_key_nullable(self) -> Self:
        # null means "remove" for the key; for any other field it is a mistake, not "keep".
        for name in self.model_fields_set - {"api_key"}:
            if getattr(self, name) is None:
                raise _invalid(
                    f"'{name}' cannot be null; leave it out to keep its value",
                    f"'{name}' no puede ser null; omítelo para conservar su valor",
                )
        return self

    def apply(self, current: PrinterConfig) -> PrinterConfig:
        """``current`` with these changes, validated again as a whole."""
        fields = {name: getattr(current, name) for name in PrinterConfig.model_fields}
        for name in self.model_fields_set:
            fields[name] = getattr(self, name)
        if self.capabilities is not None:
            caps = {name: getattr(current.capabilities, name) for name in Capabilities.model_fields}
            for name in self.capabilities.model_fields_set:
                caps[name] = getattr(self.capabilities, name)
            fields["capabilities"] = Capabilities(**caps)
        return PrinterConfig(**fields)


def slugify(name: str) -> str:
    """A valid id from a display name: 'Impresora Ñandú #2' -> 'impresora-nandu-2'."""
    ascii_name = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode()
    slug = re.sub(r"[^a-z0-9]+", "-", ascii_name.lower()).strip("-")[:64].rstrip("-")
    return slug or "printer"
