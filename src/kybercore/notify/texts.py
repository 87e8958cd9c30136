"""The words of a notification, in English and Spanish: what happened, and what to do.

Pure: :func:`render` turns an event into a (title, body) pair in a channel's language. The
title is the headline a phone shows; the body says what happened in a sentence and, where
someone has to act, what to do. Spanish addresses the operator as *usted*, as the
dashboard's queue messages do.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any, Final, Literal

from kybercore.notify.models import FleetEvent

Language = Literal["en", "es"]

_LIST_MAX: Final = 6
"""Names listed in full; more are counted ("and 7 more")."""
_QUEUE_UPLOAD: Final = re.compile(r"^j\d+-c\d+-a\d+-")
"""The prefix the queue gives its uploads on a printer (jobs.store_copies.upload_name)."""

# (kind, variant) -> (English title, English body, Spanish title, Spanish body). The fields
# are filled by _values(); a variant is picked by _variant().
_TEXTS: Final[dict[tuple[str, str], tuple[str, str, str, str]]] = {
    ("print_started", ""): (
        "{name} started a print",
        "{name} started printing {file}.",
        "{name} empezó una impresión",
        "{name} empezó a imprimir {file}.",
    ),
    ("print_completed", ""): (
        "{name} finished a print",
        "{name} finished printing {file}. Remove the print and clear the plate so the "
        "next job can start.",
        "{name} terminó una impresión",
        "{name} terminó de imprimir {file}. Retire la pieza y despeje la placa para que "
        "empiece el siguiente trabajo.",
    ),
    ("print_failed", ""): (
        "{name}: print failed",
        "{name} stopped printing {file} with an error{detail}. Check the printer before "
        "printing again.",
        "{name}: la impresión falló",
        "{name} dejó de imprimir {file} por un error{detail}. Revise la impresora antes de "
        "volver a imprimir.",
    ),
    ("print_cancelled", ""): (
        "{name}: print cancelled",
        "The print of {file} on {name} was cancelled. Clear the plate before the next job.",
        "{name}: impresión cancelada",
        "Se canceló la impresión de {file} en {name}. Despeje la placa antes del "
        "siguiente trabajo.",
    ),
    ("print_paused", "runout"): (
        "{name} paused: filament ran out",
        "{name} paused {file} because the filament ran out. Load filament and resume the print.",
        "{name} en pausa: se acabó el filamento",
        "{name} pausó {file} porque se acabó el filamento. Cargue filamento y reanude la "
        "impresión.",
    ),
    ("print_paused", ""): (
        "{name}: print paused",
        "{name} paused {file}. Check the printer, then resume or cancel the print.",
        "{name}: impresión en pausa",
        "{name} pausó {file}. Revise la impresora y después reanude o cancele la impresión.",
    ),
    ("first_layer_done", ""): (
        "{name}: first layer done",
        "{name} finished the first layer of {file}. Check that it sticks to the plate.",
        "{name}: primera capa terminada",
        "{name} terminó la primera capa de {file}. Compruebe que se adhiere a la placa.",
    ),
    ("printer_offline", "printing"): (
        "{name} went offline while printing",
        "KyberCore lost the connection to {name} while it was printing {file}. Check its "
        "power and network.",
        "{name} se desconectó mientras imprimía",
        "KyberCore perdió la conexión con {name} mientras imprimía {file}. Revise su "
        "alimentación y su red.",
    ),
    ("printer_offline", "paused"): (
        "{name} went offline with a print paused",
        "KyberCore lost the connection to {name} while {file} was paused on it. Check its "
        "power and network.",
        "{name} se desconectó con una impresión en pausa",
        "KyberCore perdió la conexión con {name} mientras tenía {file} en pausa. Revise su "
        "alimentación y su red.",
    ),
    ("printer_offline", ""): (
        "{name} is offline",
        "{name} has been offline for {minutes}. Check its power and network.",
        "{name} sigue sin conexión",
        "{name} lleva {minutes} sin conexión. Revise su alimentación y su red.",
    ),
    ("printer_recovered", "klippy"): (
        "{name}: Klipper is ready again",
        "Klipper on {name} is ready again.",
        "{name}: Klipper vuelve a estar listo",
        "Klipper en {name} vuelve a estar listo.",
    ),
    ("printer_recovered", ""): (
        "{name} is back online",
        "KyberCore is connected to {name} again.",
        "{name} vuelve a estar en línea",
        "KyberCore vuelve a estar conectado a {name}.",
    ),
    ("printer_recovered", "worker"): (
        "{name} is reported again",
        "A KyberCore worker reports {name} again: its prints and alerts are followed again.",
        "{name} vuelve a tener un worker",
        "Un worker de KyberCore vuelve a informar de {name}: sus impresiones y avisos se "
        "siguen de nuevo.",
    ),
    ("printer_recovered", "worker_fold"): (
        "{printers} reported again",
        "KyberCore workers report these printers again: {names}.",
        "{printers} vuelven a tener un worker",
        "Los workers de KyberCore vuelven a informar de estas impresoras: {names}.",
    ),
    ("printer_recovered", "fold"): (
        "{where}{printers} back online",
        "Back online: {names}.",
        "{where}{printers} de nuevo en línea",
        "De nuevo en línea: {names}.",
    ),
    ("klippy_shutdown", ""): (
        "{name}: Klipper shut down",
        "Klipper on {name} shut down{detail}. Fix the cause, then restart the firmware.",
        "{name}: Klipper se detuvo",
        "Klipper en {name} se detuvo{detail}. Corrija la causa y reinicie el firmware.",
    ),
    ("klippy_error", ""): (
        "{name}: Klipper error",
        "Klipper on {name} reports an error{detail}. Fix the cause, then restart Klipper.",
        "{name}: error de Klipper",
        "Klipper en {name} informa de un error{detail}. Corrija la causa y reinicie Klipper.",
    ),
    ("plate_waiting", ""): (
        "{name}: plate waiting to be cleared",
        "Clear the plate of {name} to let the queue continue; it has been waiting {minutes}.",
        "{name}: placa por despejar",
        "Despeje la placa de {name} para que la cola continúe; lleva {minutes} esperando.",
    ),
    ("plate_waiting", "fold"): (
        "{plates} {are} waiting to be cleared",
        "Clear the plates of {names} to let the queue continue.",
        "Hay {plates} por despejar",
        "Despeje las placas de {names} para que la cola continúe.",
    ),
    ("job_blocked", ""): (
        "Job {job} is blocked",
        "Job {job} has been blocked for {minutes}{detail}. Fix the cause, then requeue it.",
        "El trabajo {job} está bloqueado",
        "El trabajo {job} lleva {minutes} bloqueado{detail}. Corrija la causa y vuelva a "
        "ponerlo en cola.",
    ),
    ("storm_offline", ""): (
        "{where}{printers} offline",
        "{printers}{there} went offline together: {names}. Check their power and network.",
        "{where}{printers} sin conexión",
        "{printers}{there} {went_es} a la vez: {names}. Revise su alimentación y su red.",
    ),
    ("printer_unreported", ""): (
        "{name}: no KyberCore worker reports it",
        "No KyberCore worker has reported {name} for {seconds} s, so KyberCore cannot see "
        "its prints or alerts. Check that the `kybercore ingest` workers are running and "
        "reach NATS.",
        "{name}: ningún worker de KyberCore informa de ella",
        "Ningún worker de KyberCore informa de {name} desde hace {seconds} s, así que "
        "KyberCore no ve sus impresiones ni sus avisos. Compruebe que los workers "
        "`kybercore ingest` están en marcha y llegan a NATS.",
    ),
    ("printer_unreported", "fold"): (
        "{printers}: no KyberCore worker reports them",
        "No KyberCore worker reports {names}, so KyberCore cannot see their prints or "
        "alerts. Check that the `kybercore ingest` workers are running and reach NATS.",
        "{printers} sin ningún worker de KyberCore",
        "Ningún worker de KyberCore informa de {names}, así que KyberCore no ve sus "
        "impresiones ni sus avisos. Compruebe que los workers `kybercore ingest` están en "
        "marcha y llegan a NATS.",
    ),
    ("test", ""): (
        "KyberCore test notification",
        "This channel works: KyberCore can reach it.",
        "Notificación de prueba de KyberCore",
        "Este canal funciona: KyberCore puede llegar a él.",
    ),
}


def render(event: FleetEvent, language: Language) -> tuple[str, str]:
    """The event's (title, body) in ``language``."""
    en_title, en_body, es_title, es_body = _TEXTS[(event.kind, _variant(event))]
    title, body = (es_title, es_body) if language == "es" else (en_title, en_body)
    values = _values(event, language)
    return title.format_map(values), body.format_map(values)


def _variant(event: FleetEvent) -> str:
    params = event.params
    if event.printer is None and event.kind == "printer_recovered":
        return "worker_fold" if params.get("what") == "worker" else "fold"
    if event.printer is None and event.kind in ("plate_waiting", "printer_unreported"):
        return "fold"
    if event.kind == "print_paused":
        return "runout" if params.get("reason") == "runout" else ""
    if event.kind == "printer_offline":
        return "printing" if params.get("was") == "printing" else str(params.get("was") or "")
    if event.kind == "printer_recovered":
        what = params.get("what")
        return what if what in ("klippy", "worker") else ""
    return ""


def _values(event: FleetEvent, language: Language) -> dict[str, str]:
    params = event.params
    es = language == "es"
    names = params.get("names") or params.get("printers") or []
    count = _count(params.get("count"), len(names))
    location = _clean(params.get("location"))
    printer = event.printer
    detail = _clean(params.get(f"reason_{language}") or params.get("reason"))
    if event.kind != "job_blocked":
        detail = _clean(params.get("message"))
    return {
        "name": printer.name if printer else _clean(params.get("name")) or "?",
        "file": display_file(params.get("filename")) or ("el archivo" if es else "the file"),
        "detail": f": {detail}" if detail else "",
        "minutes": _plural(_count(params.get("minutes"), 0), "minuto" if es else "minute"),
        "seconds": str(_count(params.get("seconds"), 0)),
        "job": _clean(params.get("job_name")) or f"#{_clean(params.get('job_id')) or '?'}",
        "names": listing([str(n) for n in names], language) if names else "?",
        "where": f"{location}: " if location else "",
        "there": f" {'de' if es else 'in'} {location}" if location else "",
        "printers": _plural(count, "impresora" if es else "printer"),
        "plates": _plural(count, "placa" if es else "plate"),
        "are": "is" if count == 1 else "are",
        "went_es": "se desconectó" if count == 1 else "se desconectaron",
    }


def _clean(value: Any) -> str:
    """A parameter as one line of text without a closing full stop (the template adds
    its own punctuation)."""
    if value is None:
        return ""
    return " ".join(str(value).split()).rstrip(".")


def _count(value: Any, default: int) -> int:
    return value if isinstance(value, int) and not isinstance(value, bool) else default


def _plural(count: int, word: str) -> str:
    """``1 printer``, ``3 printers``; ``1 impresora``, ``3 impresoras`` (every word used
    here takes an s in both languages)."""
    return f"{count} {word}" if count == 1 else f"{count} {word}s"


def listing(names: Sequence[str], language: Language) -> str:
    """``a, b and c`` (``a, b y c``); past a handful, the rest counted."""
    conj, more = (" y ", "{} más") if language == "es" else (" and ", "{} more")
    shown = list(names[:_LIST_MAX])
    if len(names) > _LIST_MAX:
        shown = [*names[: _LIST_MAX - 1], more.format(len(names) - _LIST_MAX + 1)]
    if len(shown) <= 1:
        return "".join(shown)
    return ", ".join(shown[:-1]) + conj + shown[-1]


def display_file(filename: Any) -> str:
    """A printer's file as a person knows it: its name without folders, and for the
    queue's uploads without the job/copy/attempt prefix."""
    if not isinstance(filename, str) or not filename:
        return ""
    base = filename.rsplit("/", 1)[-1]
    if filename.startswith("kybercore/"):
        base = _QUEUE_UPLOAD.sub("", base)
    return base
