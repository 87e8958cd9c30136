"""Why a job waits: one short line per printer (or power group, or the queue), en and es.

A :class:`WhyLine` has a stable snake_case ``code`` the dashboard and scripts may rely on,
so a code never changes meaning once released. Lines that repeat a validation finding
(``file_too_tall``, ``filament_mismatch``…) keep that finding's code from
:mod:`kybercore.core.messages` and its full message.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from kybercore.core.messages import Reason


@dataclass(frozen=True)
class WhyLine:
    """One reason a job is not running somewhere right now."""

    subject: str
    """A printer id, ``"power group <name>"`` or ``"queue"`` (the job as a whole)."""
    code: str
    en: str
    es: str

    def __str__(self) -> str:
        return f"{self.subject}: {self.en}"


QUEUE: Final = "queue"
"""The subject of a line about the job itself rather than one printer."""

# code: (English, Spanish). Placeholders are filled by ``line``.
MESSAGES: Final[dict[str, tuple[str, str]]] = {
    # --- the job as a whole (subject "queue") ---
    "queue_paused": ("the queue is paused; resume it to dispatch jobs",
        "la cola está en pausa; reanúdela para enviar trabajos"),
    "not_before": ("waits until {time}", "espera hasta {time}"),
    "job_blocked": ("blocked: {reason} Requeue it once the cause is fixed.",
        "bloqueado: {reason} Vuelva a ponerlo en cola cuando la causa esté corregida."),
    "job_done": ("done: every copy is printed", "terminado: todas las copias están impresas"),
    "job_cancelled": ("cancelled", "cancelado"),
    "no_copies_left": ("every copy left is printing or awaiting a verdict",
        "todas las copias pendientes se están imprimiendo o esperan veredicto"),
    "no_printers": ("no printers are configured; add one",
        "no hay impresoras configuradas; añada una"),
    "pinned": ("pinned to {printer}: no other printer is considered",
        "fijado a {printer}: no se considera ninguna otra impresora"),
    "pinned_unknown": ("the job is pinned to this printer, which is not configured",
        "el trabajo está fijado a esta impresora, que no está configurada"),
    # --- what the job requires of a printer ---
    "needs_material": ("{loaded} loaded, job needs {material}",
        "tiene {loaded} cargado, el trabajo necesita {material}"),
    "material_unknown": ("no loaded material recorded, job needs {material}; set it in the "
        "printer's settings",
        "no consta el material cargado y el trabajo necesita {material}; indíquelo en la "
        "configuración de la impresora"),
    "needs_nozzle": ("{ours} mm nozzle, job needs {nozzle} mm",
        "boquilla de {ours} mm, el trabajo necesita {nozzle} mm"),
    "nozzle_unknown": ("nozzle size unknown, job needs {nozzle} mm",
        "tamaño de boquilla desconocido, el trabajo necesita {nozzle} mm"),
    "needs_model": ("model '{ours}', job needs '{model}'",
        "modelo «{ours}», el trabajo necesita «{model}»"),
    "needs_tags": ("lacks tag {tags}", "le falta la etiqueta {tags}"),
    # --- the printer's state now ---
    "printer_offline": ("offline", "desconectada"),
    "printer_disabled": ("disabled in KyberCore", "desactivada en KyberCore"),
    "printer_connecting": ("connecting", "conectando"),
    "printer_auth_failed": ("Moonraker refuses its API key",
        "Moonraker rechaza su clave API"),
    "klippy_not_ready": ("Klipper is {state}, not ready", "Klipper está en {state}, no listo"),
    "awaiting_clear": ("awaiting clear since {since}",
        "esperando que se retire la pieza desde {since}"),
    "held": ("held{detail}", "retenida{detail}"),
    "maintenance": ("in maintenance{detail}", "en mantenimiento{detail}"),
    "printer_busy": ("busy: {state_en}", "ocupada: {state_es}"),
    "printer_starting": ("starting attempt {attempt}", "iniciando el intento {attempt}"),
    "print_state_unknown": ("print state unknown ({state})",
        "estado de impresión desconocido ({state})"),
    # --- the round: power, other jobs ---
    "waiting_for_power": ("{heating} of {budget} heating; {printers} wait",
        "{heating} de {budget} calentando; esperan {printers}"),
    "taken_by_job": ("goes to job {job} first (ahead in the queue)",
        "va antes al trabajo {job} (por delante en la cola)"),
    "ranked_lower": ("could print it, but the copies left go to less-used printers",
        "podría imprimirlo, pero las copias pendientes van a impresoras menos usadas"),
    "assigned": ("gets a copy in the next dispatch round",
        "recibe una copia en la próxima ronda de envío"),
    "eligible": ("could print it once the queue sends it",
        "podría imprimirlo cuando la cola lo envíe"),
    # --- never printable (reject at submission) ---
    "no_model": ("no printer is a '{model}' (models: {models})",
        "ninguna impresora es «{model}» (modelos: {models})"),
    "no_tags": ("no printer has every tag of {tags}",
        "ninguna impresora tiene todas las etiquetas {tags}"),
    "no_nozzle": ("no printer has a {nozzle} mm nozzle (nozzles: {nozzles})",
        "ninguna impresora tiene boquilla de {nozzle} mm (boquillas: {nozzles})"),
    "too_tall": ("the part is {height} mm tall; the tallest Z travel is {z} mm",
        "la pieza mide {height} mm de alto; el mayor recorrido en Z es de {z} mm"),
    "too_hot": ("the first layer heats the {heater_en} to {temp} °C; the highest maximum is "
        "{limit} °C",
        "la primera capa calienta {heater_es} a {temp} °C; el máximo más alto es de {limit} °C"),
    "no_printer_fits": ("no single printer meets all of: {needs_en}",
        "ninguna impresora cumple a la vez: {needs_es}"),
}  # fmt: skip


# A validation warning the job does not accept: the warning's own text, then what to do.
_MISMATCH: Final = (
    "{detail} The job does not allow a mismatch: queue it with allow mismatch to dispatch "
    "it anyway.",
    "{detail} El trabajo no admite discrepancias: póngalo en cola permitiéndolas para "
    "enviarlo de todos modos.",
)


def line(subject: str, code: str, **values: str | float) -> WhyLine:
    """The catalogued line ``code`` about ``subject``, placeholders filled per language.

    Numbers are written the way each language writes them; a value named ``*_en`` or
    ``*_es`` is for that language's message only."""
    en, es = MESSAGES[code]
    return WhyLine(
        subject,
        code,
        en.format(**{k: v if isinstance(v, str) else number(v) for k, v in values.items()}),
        es.format(**{k: v if isinstance(v, str) else number(v, "es") for k, v in values.items()}),
    )


def finding(subject: str, found: Reason, *, mismatch: bool = False) -> WhyLine:
    """A validation finding as a line, under the finding's own code and message.

    ``mismatch``: a warning the job does not accept (it does not allow a mismatch); the
    line then says how to accept it."""
    if not mismatch:
        return WhyLine(subject, found.code, found.en, found.es)
    en, es = _MISMATCH
    return WhyLine(subject, found.code, en.format(detail=found.en), es.format(detail=found.es))


def number(value: float, language: str = "en") -> str:
    """``value`` short (``0.4``), with a decimal comma in Spanish (``0,4``)."""
    text = f"{value:g}"
    return text.replace(".", ",") if language == "es" else text
