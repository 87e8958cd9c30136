"""The rules of a change to the fleet's list of printers, whatever stores it.

Pure: each function changes the list it is given (in place) and returns the printer as
stored, or raises the error that says why the change is refused. ``printers.json``
(:mod:`kybercore.registry.store`) and the NATS key-value registry
(:mod:`kybercore.scale.registry`) both apply them, so both refuse the same things in the
same words.
"""

from __future__ import annotations

from kybercore.errors import InvalidInput, UnknownPrinter
from kybercore.registry.models import (
    PrinterConfig,
    PrinterCreate,
    PrinterUpdate,
    server_of,
    slugify,
)


def add_printer(printers: list[PrinterConfig], new: PrinterCreate) -> PrinterConfig:
    """Append ``new`` and return it as stored.

    A given id that exists raises InvalidInput; an id derived from the name gets a ``-2``,
    ``-3``... suffix instead.
    """
    taken = {p.id for p in printers}
    if new.id is not None and new.id in taken:
        english = (
            f"A printer with id '{new.id}' already exists. Choose another id, or "
            "edit the existing printer."
        )
        # The dashboard shows reasons in its language; this one has no other source.
        spanish = (
            f"Ya existe una impresora con el id '{new.id}'. Elige otro id o edita "
            "la impresora existente."
        )
        reason = {"code": "id_taken", "level": "block", "category": "input"}
        raise InvalidInput(english, reasons=[{**reason, "en": english, "es": spanish}])
    printer = new.to_config(new.id or _free_id(slugify(new.name), taken))
    _refuse_same_server(printer, printers)
    printers.append(printer)
    return printer


def update_printer(
    printers: list[PrinterConfig], printer_id: str, patch: PrinterUpdate
) -> PrinterConfig:
    """Apply ``patch`` to printer ``printer_id`` and return it as stored.

    A stored API key never follows the printer to another server: a patch that moves
    ``moonraker_url`` to another scheme, host or port must give ``api_key`` again (or null
    to drop it), else InvalidInput. The key is write-only, so whoever can edit the URL
    could otherwise have KyberCore send it to a host of their choosing.
    """
    index = index_of(printers, printer_id)
    current, updated = printers[index], patch.apply(printers[index])
    if (
        current.api_key is not None
        and "api_key" not in patch.model_fields_set
        and server_of(current.moonraker_url) != server_of(updated.moonraker_url)
    ):
        raise _key_needed(updated.moonraker_url)
    # Only a move is judged: a hand-written file sharing a server stays editable.
    if server_of(current.moonraker_url) != server_of(updated.moonraker_url):
        _refuse_same_server(updated, printers)
    printers[index] = updated
    return updated


def remove_printer(printers: list[PrinterConfig], printer_id: str) -> PrinterConfig:
    """Remove printer ``printer_id`` and return what it was."""
    return printers.pop(index_of(printers, printer_id))


def index_of(printers: list[PrinterConfig], printer_id: str) -> int:
    """Where printer ``printer_id`` is in ``printers``; UnknownPrinter when it is not."""
    for index, printer in enumerate(printers):
        if printer.id == printer_id:
            return index
    raise UnknownPrinter(printer_id)


def _refuse_same_server(printer: PrinterConfig, printers: list[PrinterConfig]) -> None:
    """One Moonraker drives one printer: a second entry for the same server would show the
    same machine twice and let the queue send it two jobs at once."""
    server = server_of(printer.moonraker_url)
    other = next(
        (p for p in printers if p.id != printer.id and server_of(p.moonraker_url) == server),
        None,
    )
    if other is None:
        return
    english = (
        f"Printer '{other.name}' ({other.id}) already uses {printer.moonraker_url}. One "
        "Moonraker drives one printer: check the address, or edit the existing printer."
    )
    spanish = (
        f"La impresora '{other.name}' ({other.id}) ya usa {printer.moonraker_url}. Un "
        "Moonraker controla una sola impresora: revisa la dirección o edita la existente."
    )
    reason = {"code": "url_taken", "level": "block", "category": "input", "field": "moonraker_url"}
    raise InvalidInput(english, reasons=[{**reason, "en": english, "es": spanish}])


def _key_needed(url: str) -> InvalidInput:
    english = (
        f"The printer moves to another server ({url}): give its Moonraker API key again "
        "(api_key, or --api-key), or remove the stored key (api_key: null, or "
        "--clear-api-key). A stored key is never sent to a new host."
    )
    spanish = (
        f"La impresora pasa a otro servidor ({url}): indica de nuevo su clave de API de "
        "Moonraker (api_key o --api-key) o borra la guardada (api_key: null o "
        "--clear-api-key). Una clave guardada nunca se envía a otro host."
    )
    reason = {"code": "api_key_needed", "level": "block", "category": "input"}
    return InvalidInput(english, reasons=[{**reason, "en": english, "es": spanish}])


def _free_id(base: str, taken: set[str]) -> str:
    candidate, n = base, 1
    while candidate in taken:
        n += 1
        suffix = f"-{n}"
        candidate = base[: 64 - len(suffix)] + suffix
    return candidate
