"""``kybercore printers list|add|edit|remove``: manage printers.json from a shell; and
``kybercore printers clear|hold|release``: the plate gate of a printer, on a running
KyberCore (through its REST API, :mod:`kybercore.cli.remote`).

Safe while the server runs: every change goes through :class:`PrinterRegistry`, which
locks the file against the server's own writes, and the server picks the change up.
Errors print one red ``Error: ...`` line and exit 1 (the file or the fleet) or 2 (the input).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import AbstractContextManager as ContextManager
from contextlib import contextmanager
from typing import Annotated, Any, TypeVar

import typer
from pydantic import ValidationError
from rich.table import Table
from rich.text import Text

from kybercore.cli.audit import CliAction, audited
from kybercore.cli.options import PrintersFile, ServerUrl, Token
from kybercore.cli.output import done, fail, print_table
from kybercore.cli.remote import DEFAULT_URL, Remote, remote_errors
from kybercore.errors import InvalidInput, KyberCoreError
from kybercore.registry.models import PrinterCreate, PrinterUpdate
from kybercore.registry.store import PrinterRegistry

printers_app = typer.Typer(
    help="List, add, edit and remove the printers in printers.json; clear, hold and "
    "release their plates for the job queue.",
    no_args_is_help=True,
)

# CLI option names for the model fields whose flag is not `--field-name`, so a validation
# error names what the user typed.
_OPTION = {
    "name": "NAME / --name",
    "moonraker_url": "--url",
    "tags": "--tag",
    "capabilities.build_volume": "--size",
    "capabilities.nozzle_diameter": "--nozzle",
    "capabilities.material": "--material",
    "capabilities.max_extruder_temp": "--max-extruder-temp",
    "capabilities.max_bed_temp": "--max-bed-temp",
}
_FILE_KEY = "kybercore.printers_file"
M = TypeVar("M", PrinterCreate, PrinterUpdate)

ModelOpt = Annotated[str | None, typer.Option("--model", help="Printer model, e.g. 'Voron 2.4'.")]
LocationOpt = Annotated[str | None, typer.Option("--location", help="Where the printer is.")]
PowerGroupOpt = Annotated[
    str | None,
    typer.Option(
        "--power-group",
        help="The circuit it shares with others (the queue's heating budget); default: location.",
    ),
]
SiteOpt = Annotated[
    str | None,
    typer.Option(
        "--site",
        help="Whose workers connect to it on NATS (kybercore ingest --site); default: none.",
    ),
]
NotesOpt = Annotated[str | None, typer.Option("--notes", help="Free text for operators.")]
TagOpt = Annotated[
    list[str] | None,
    typer.Option("--tag", metavar="TAG", help="A label; repeat for several.", show_default=False),
]
ApiKeyOpt = Annotated[
    str | None,
    typer.Option("--api-key", help="Moonraker API key (stored in printers.json, never shown)."),
]
SizeOpt = Annotated[
    tuple[float, float, float] | None,
    typer.Option("--size", metavar="X Y Z", help="Build volume in mm.", show_default=False),
]
NozzleOpt = Annotated[float | None, typer.Option("--nozzle", help="Nozzle diameter in mm.")]
MaterialOpt = Annotated[str | None, typer.Option("--material", help="Loaded filament, e.g. PLA.")]
ExtruderOpt = Annotated[
    float | None, typer.Option("--max-extruder-temp", help="Highest hotend temperature, °C.")
]
BedOpt = Annotated[
    float | None, typer.Option("--max-bed-temp", help="Highest bed temperature, °C.")
]


@printers_app.callback()
def _options(ctx: typer.Context, printers_file: PrintersFile = None) -> None:
    """List, add, edit and remove the printers in printers.json."""
    ctx.meta[_FILE_KEY] = printers_file


@printers_app.command("list")
def list_printers(
    ctx: typer.Context,
    as_json: Annotated[bool, typer.Option("--json", help="Print the public JSON.")] = False,
) -> None:
    """Show every printer (API keys only as set / not set)."""
    with _errors():
        registry = _registry(ctx)
        printers = registry.reload()
    if as_json:
        public = [p.public().model_dump(mode="json") for p in printers]
        typer.echo(json.dumps(public, indent=2, ensure_ascii=False))
        return
    if not printers:
        typer.echo(f"No printers in {registry.path}. Add one with `kybercore printers add`.")
        return
    table = Table(title=Text(str(registry.path)))
    for column in ("id", "name", "model", "location", "URL", "enabled", "API key"):
        table.add_column(column)
    for p in printers:
        table.add_row(
            *(Text(value) for value in (p.id, p.name, p.model, p.location, p.moonraker_url)),
            "yes" if p.enabled else "no",
            "set" if p.api_key else "not set",
        )
    print_table(table)


@printers_app.command("add")
def add_printer(
    ctx: typer.Context,
    name: Annotated[str, typer.Argument(help="Name shown to people.")],
    url: Annotated[str, typer.Option("--url", help="Moonraker URL, e.g. http://10.0.0.5:7125.")],
    printer_id: Annotated[
        str | None, typer.Option("--id", help="Id (slug); derived from NAME if omitted.")
    ] = None,
    model: ModelOpt = None,
    location: LocationOpt = None,
    power_group: PowerGroupOpt = None,
    site: SiteOpt = None,
    notes: NotesOpt = None,
    tag: TagOpt = None,
    api_key: ApiKeyOpt = None,
    disabled: Annotated[bool, typer.Option("--disabled", help="Add it switched off.")] = False,
    size: SizeOpt = None,
    nozzle: NozzleOpt = None,
    material: MaterialOpt = None,
    max_extruder_temp: ExtruderOpt = None,
    max_bed_temp: BedOpt = None,
) -> None:
    """Add a printer."""
    fields = {
        "id": printer_id,
        "name": name,
        "moonraker_url": url,
        "model": model,
        "location": location,
        "power_group": power_group,
        "site": site,
        "notes": notes,
        "tags": tag,
        "api_key": api_key,
        "enabled": not disabled,
        "capabilities": _capabilities(size, nozzle, material, max_extruder_temp, max_bed_temp),
    }
    given = {k: v for k, v in fields.items() if v is not None}
    target = f"printer:{printer_id}" if printer_id else ""
    with _errors(), _audited(ctx, CliAction("printer.add", target, given)) as action:
        printer = _registry(ctx).add(_build(PrinterCreate, **fields))
        action.target = f"printer:{printer.id}"
    done(f"Added printer '{printer.id}' ({printer.name}) at {printer.moonraker_url}.")


@printers_app.command("edit")
def edit_printer(
    ctx: typer.Context,
    printer_id: Annotated[str, typer.Argument(metavar="ID", help="Id of the printer to edit.")],
    name: Annotated[str | None, typer.Option("--name", help="New name.")] = None,
    url: Annotated[str | None, typer.Option("--url", help="New Moonraker URL.")] = None,
    model: ModelOpt = None,
    location: LocationOpt = None,
    power_group: PowerGroupOpt = None,
    site: SiteOpt = None,
    notes: NotesOpt = None,
    tag: TagOpt = None,
    api_key: ApiKeyOpt = None,
    clear_api_key: Annotated[
        bool, typer.Option("--clear-api-key", help="Remove the stored API key.")
    ] = False,
    enabled: Annotated[
        bool | None, typer.Option("--enable/--disable", help="Switch it on or off.")
    ] = None,
    size: SizeOpt = None,
    nozzle: NozzleOpt = None,
    material: MaterialOpt = None,
    max_extruder_temp: ExtruderOpt = None,
    max_bed_temp: BedOpt = None,
) -> None:
    """Change a printer; options not given keep their value (--tag replaces all tags)."""
    changes: dict[str, Any] = {
        "name": name,
        "moonraker_url": url,
        "model": model,
        "location": location,
        "power_group": power_group,
        "site": site,
        "notes": notes,
        "tags": tag,
        "api_key": api_key,
        "enabled": enabled,
        "capabilities": _capabilities(size, nozzle, material, max_extruder_temp, max_bed_temp),
    }
    if clear_api_key and api_key is None:
        changes["api_key"] = ""  # PATCH semantics: "" removes the key
    given = {k: v for k, v in changes.items() if v is not None}
    with _errors(), _audited(ctx, CliAction("printer.edit", f"printer:{printer_id}", given)):
        if clear_api_key and api_key is not None:
            raise InvalidInput("Give either --api-key or --clear-api-key, not both.")
        patch = _build(PrinterUpdate, **changes)
        if not patch.model_fields_set:
            raise InvalidInput("Nothing to change: give at least one option (see --help).")
        printer = _registry(ctx).update(printer_id, patch)
    done(f"Updated printer '{printer.id}' ({printer.name}).")


@printers_app.command("remove")
def remove_printer(
    ctx: typer.Context,
    printer_id: Annotated[str, typer.Argument(metavar="ID", help="Id of the printer to remove.")],
    yes: Annotated[bool, typer.Option("--yes", "-y", help="Do not ask for confirmation.")] = False,
) -> None:
    """Remove a printer from printers.json."""
    with _errors():
        registry = _registry(ctx)
        registry.reload()
        printer = registry.get(printer_id)
    if not yes and not typer.confirm(f"Remove printer '{printer.id}' ({printer.name})?"):
        typer.echo("Nothing removed.")
        raise typer.Exit(1)
    with _errors(), _audited(ctx, CliAction("printer.remove", f"printer:{printer_id}")):
        registry.remove(printer_id)
    done(f"Removed printer '{printer_id}'.")


PrinterIdArg = Annotated[str, typer.Argument(metavar="ID", help="The printer's id.")]


@printers_app.command("clear")
def clear_plate(
    printer_id: PrinterIdArg,
    good: Annotated[
        bool | None,
        typer.Option(
            "--good/--bad",
            help="--good: the copy counts as done; --bad: it goes back to the queue.",
            show_default=False,
        ),
    ] = None,
    cause: Annotated[str, typer.Option(help="Why the print is bad (optional).")] = "",
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """Say the plate of a printer awaiting a clear is empty, and how the print came out."""
    if good is None:
        raise fail("Say how the print came out: --good or --bad.", code=2)
    verdict = "good" if good else "bad"
    with remote_errors(), Remote(url, token) as remote:
        remote.call(
            "POST", f"/api/printers/{printer_id}/clear", json={"verdict": verdict, "cause": cause}
        )
    counted = "counted as done" if good else "sent back to the queue"
    done(f"Cleared {printer_id}: the copy is {counted}; the printer takes the next one.")


@printers_app.command("hold")
def hold(
    printer_id: PrinterIdArg,
    reason: Annotated[str, typer.Option(help="Why, shown to everyone (e.g. 'nozzle change').")],
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """Keep the job queue off a printer until it is released."""
    with remote_errors(), Remote(url, token) as remote:
        remote.call("POST", f"/api/printers/{printer_id}/hold", json={"reason": reason})
    done(f"Held {printer_id}: the queue sends it nothing until `kybercore printers release`.")


@printers_app.command("release")
def release(printer_id: PrinterIdArg, url: ServerUrl = DEFAULT_URL, token: Token = None) -> None:
    """Give a held printer back to the job queue."""
    with remote_errors(), Remote(url, token) as remote:
        remote.call("POST", f"/api/printers/{printer_id}/release")
    done(f"Released {printer_id}: the queue may send it the next copy.")


def _registry(ctx: typer.Context) -> PrinterRegistry:
    return PrinterRegistry(ctx.meta.get(_FILE_KEY))


def _audited(ctx: typer.Context, action: CliAction) -> ContextManager[CliAction]:
    """Record the change in the audit log (:mod:`kybercore.cli.audit`)."""
    return audited(ctx.meta.get(_FILE_KEY), action)


def _capabilities(
    size: tuple[float, float, float] | None,
    nozzle: float | None,
    material: str | None,
    max_extruder_temp: float | None,
    max_bed_temp: float | None,
) -> dict[str, Any] | None:
    """Only the capabilities given, so an edit keeps the others (PATCH merges them)."""
    given = {
        "build_volume": dict(zip("xyz", size, strict=True)) if size else None,
        "nozzle_diameter": nozzle,
        "material": material,
        "max_extruder_temp": max_extruder_temp,
        "max_bed_temp": max_bed_temp,
    }
    caps = {k: v for k, v in given.items() if v is not None}
    return caps or None


def _build(kind: type[M], /, **fields: Any) -> M:
    """Validate CLI input as the API would, naming the offending option on error."""
    try:
        return kind.model_validate({k: v for k, v in fields.items() if v is not None})
    except ValidationError as exc:
        error = exc.errors(include_input=False)[0]
        field = ".".join(str(part) for part in error["loc"] if not isinstance(part, int))
        reason = str(error["ctx"]["error"]) if error["type"] == "value_error" else error["msg"]
        raise InvalidInput(f"{_option(field)}: {reason}.") from None


def _option(field: str) -> str:
    """The CLI option for a model field, e.g. 'capabilities.build_volume.x' -> '--size'."""
    for prefix, option in _OPTION.items():
        if field == prefix or field.startswith(prefix + "."):
            return option
    return "--" + field.replace("_", "-")


@contextmanager
def _errors() -> Iterator[None]:
    """Turn KyberCore's errors into one red line and an exit code, never a traceback."""
    try:
        yield
    except InvalidInput as exc:
        raise fail(exc.message, code=2) from None
    except KyberCoreError as exc:
        raise fail(exc.message, code=1) from None
