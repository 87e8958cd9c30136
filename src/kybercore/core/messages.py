"""The catalogue of validation reasons: a stable code, a level, a category, en and es.

The fleet service and the dashboard rely on the codes, so a code never changes meaning once
released. Messages say what is wrong and what to do; placeholders are filled by
:func:`reason`, each number written the way its language writes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

Level = Literal["ok", "warn", "block"]
Category = Literal["state", "limit", "compatibility", "connection", "advisor"]

_FORCE_EN: Final = "Cancel the print first, or repeat with force=true if you accept losing it."
_FORCE_ES: Final = (
    "Cancele antes la impresión o repita la acción con force=true si acepta perderla."
)

# code: (level, category, English, Spanish). Placeholders are filled by ``reason``; the
# fleet service and the UI rely on the codes, so they never change meaning once released.
MESSAGES: Final[dict[str, tuple[Level, Category, str, str]]] = {
    "unknown_action": ("block", "limit",
        "Unknown action '{action}'. Valid actions: {valid}.",
        "Acción desconocida «{action}». Acciones válidas: {valid}."),
    "printer_offline": ("block", "connection",
        "The printer is offline: KyberCore cannot reach its Moonraker. Check that it is "
        "powered on and on the network; KyberCore reconnects by itself.",
        "La impresora está desconectada: KyberCore no puede comunicarse con su Moonraker. "
        "Compruebe que esté encendida y conectada a la red; KyberCore se reconectará solo."),
    "printer_disabled": ("block", "state",
        "The printer is disabled in KyberCore. Enable it in its settings first.",
        "La impresora está desactivada en KyberCore. Actívela primero en su configuración."),
    "printer_connecting": ("block", "connection",
        "KyberCore is still connecting to this printer. Wait a few seconds and try again.",
        "KyberCore todavía se está conectando a esta impresora. Espere unos segundos y "
        "vuelva a intentarlo."),
    "printer_auth_failed": ("block", "connection",
        "Moonraker refused KyberCore's API key. Set the right key for this printer in "
        "printers.json or with `kybercore printers edit`.",
        "Moonraker ha rechazado la clave API de KyberCore. Configure la clave correcta de "
        "esta impresora en printers.json o con `kybercore printers edit`."),
    "klippy_shutdown": ("block", "state",
        "Klipper is shut down. Only a firmware restart brings it back: find the cause in the "
        "console, fix it, then restart the firmware.",
        "Klipper está detenido por un fallo (shutdown). Solo un reinicio del firmware lo "
        "recupera: busque la causa en la consola, corríjala y reinicie el firmware."),
    "restart_after_shutdown": ("block", "state",
        "Klipper is shut down, and its MCU with it: a Klipper restart cannot configure a "
        "shut-down MCU and would leave Klipper in error. Use firmware restart instead.",
        "Klipper está detenido y su MCU también: reiniciar Klipper no puede configurar una "
        "MCU detenida y dejaría Klipper en error. Use el reinicio del firmware."),
    "klippy_error": ("block", "state",
        "Klipper reported an error, often in its configuration. Only a firmware restart or a "
        "restart is possible: fix the cause shown in the console, then restart.",
        "Klipper ha informado de un error, a menudo de configuración. Solo se puede reiniciar "
        "el firmware o Klipper: corrija la causa que muestra la consola y reinicie."),
    "klippy_startup": ("block", "state",
        "Klipper is starting up. Wait a few seconds until it is ready and try again.",
        "Klipper se está iniciando. Espere unos segundos a que esté listo y vuelva a "
        "intentarlo."),
    "klippy_disconnected": ("block", "state",
        "Moonraker answers but Klipper is not connected to it. Wait for Klipper to start; if "
        "it does not, check the Klipper service on the printer's host.",
        "Moonraker responde, pero Klipper no está conectado. Espere a que Klipper arranque; "
        "si no lo hace, revise el servicio de Klipper en el equipo de la impresora."),
    "print_in_progress": ("block", "state",
        "A print is already running or paused on this printer. Wait for it to finish or "
        "cancel it before starting another.",
        "Esta impresora ya tiene una impresión en curso o en pausa. Espere a que termine o "
        "cancélela antes de iniciar otra."),
    "pause_not_printing": ("block", "state",
        "Nothing is printing, so there is nothing to pause.",
        "No hay ninguna impresión en curso, así que no hay nada que pausar."),
    "resume_not_paused": ("block", "state",
        "The printer is not paused, so there is nothing to resume.",
        "La impresora no está en pausa, así que no hay nada que reanudar."),
    "cancel_no_print": ("block", "state",
        "There is no running or paused print to cancel.",
        "No hay ninguna impresión en curso ni en pausa que cancelar."),
    "home_while_printing": ("block", "state",
        "Homing now would ruin the current print. Wait for it to finish or cancel it first.",
        "Hacer homing de los ejes ahora arruinaría la impresión actual. Espere a que termine "
        "o cancélela antes."),
    "restart_while_printing": ("block", "state",
        "{doing_en} now would abort the running or paused print. " + _FORCE_EN,
        "{doing_es} ahora abortaría la impresión en curso o en pausa. " + _FORCE_ES),
    "gcode_restart_while_printing": ("block", "state",
        "Sending {commands} now would abort the running or paused print. " + _FORCE_EN,
        "Enviar {commands} ahora abortaría la impresión en curso o en pausa. " + _FORCE_ES),
    "gcode_home_while_printing": ("block", "state",
        "G28 now would ruin the running or paused print. " + _FORCE_EN,
        "G28 ahora arruinaría la impresión en curso o en pausa. " + _FORCE_ES),
    "forced_during_print": ("warn", "state",
        "Forced during a print: the print will be lost.",
        "Acción forzada durante una impresión: la impresión se perderá."),
    "limits_loading": ("block", "state",
        "KyberCore is still reading this printer's limits (maximum temperatures, build "
        "volume, nozzle) from Klipper after connecting, and checks this action against them. "
        "Try again in a few seconds.",
        "KyberCore todavía está leyendo de Klipper los límites de esta impresora "
        "(temperaturas máximas, volumen de impresión, boquilla) tras conectarse, y comprueba "
        "esta acción con ellos. Vuelva a intentarlo en unos segundos."),
    "limits_unknown": ("block", "state",
        "KyberCore could not read this printer's limits (maximum temperatures, build volume, "
        "nozzle) from Klipper, so it cannot check this action against them. It keeps "
        "retrying by itself; to act now, set the limits in the printer's settings "
        "(printers.json). Emergency stop always works.",
        "KyberCore no ha podido leer de Klipper los límites de esta impresora (temperaturas "
        "máximas, volumen de impresión, boquilla), así que no puede comprobar esta acción con "
        "ellos. Sigue reintentándolo por sí solo; para actuar ya, indique los límites en la "
        "configuración de la impresora (printers.json). La parada de emergencia siempre "
        "funciona."),
    "filename_missing": ("block", "limit",
        "Say which file to use (parameter 'filename').",
        "Indique qué archivo usar (parámetro «filename»)."),
    "file_metadata_missing": ("warn", "compatibility",
        "KyberCore has no metadata for this file, so height, nozzle, filament and "
        "temperatures were not checked. Confirm only if you know it suits this printer.",
        "KyberCore no tiene metadatos de este archivo, así que no se han comprobado altura, "
        "boquilla, filamento ni temperaturas. Confirme solo si sabe que es adecuado para esta "
        "impresora."),
    "file_too_tall": ("block", "compatibility",
        "The part is {height} mm tall but this printer's Z travel is {z} mm. Send it to a "
        "taller printer or re-slice it smaller.",
        "La pieza mide {height} mm de alto, pero el recorrido en Z de esta impresora es de "
        "{z} mm. Envíela a una impresora más alta o vuelva a laminarla más pequeña."),
    "nozzle_mismatch": ("block", "compatibility",
        "The file was sliced for a {file} mm nozzle but this printer has {ours} mm. Re-slice "
        "it for {ours} mm or send it to a printer with a {file} mm nozzle.",
        "El archivo se laminó para una boquilla de {file} mm, pero esta impresora tiene una "
        "de {ours} mm. Vuelva a laminarlo para {ours} mm o envíelo a una impresora con "
        "boquilla de {file} mm."),
    "not_enough_filament": ("block", "compatibility",
        "The file needs {needed} g of filament but the loaded spool has {left} g left. Load "
        "a fuller spool (and set it active in Spoolman), or send the file to another printer.",
        "El archivo necesita {needed} g de filamento, pero a la bobina cargada le quedan "
        "{left} g. Cargue una bobina con más filamento (y márquela activa en Spoolman) o "
        "envíe el archivo a otra impresora."),
    "filament_mismatch": ("warn", "compatibility",
        "The file was sliced for {file} but {loaded} is loaded. Load {file}, or confirm if "
        "you know this filament prints with that profile.",
        "El archivo se laminó para {file}, pero hay cargado {loaded}. Cargue {file} o "
        "confirme si sabe que este filamento sirve con ese perfil."),
    "file_extruder_temp_over_max": ("block", "limit",
        "The file heats the nozzle to {temp} °C for the first layer, above this printer's "
        "maximum of {limit} °C. Re-slice it with a lower temperature or use a printer rated "
        "for it.",
        "El archivo calienta la boquilla a {temp} °C en la primera capa, por encima del "
        "máximo de esta impresora ({limit} °C). Vuelva a laminarlo con una temperatura más "
        "baja o use una impresora preparada para ella."),
    "file_bed_temp_over_max": ("block", "limit",
        "The file heats the bed to {temp} °C for the first layer, above this printer's "
        "maximum of {limit} °C. Re-slice it with a lower temperature or use a printer rated "
        "for it.",
        "El archivo calienta la cama a {temp} °C en la primera capa, por encima del máximo "
        "de esta impresora ({limit} °C). Vuelva a laminarlo con una temperatura más baja o "
        "use una impresora preparada para ella."),
    "printer_model_mismatch": ("warn", "compatibility",
        "The file was sliced for a '{file}' but this printer is a '{ours}'. Check that its "
        "start G-code and bed size suit this printer, or re-slice it.",
        "El archivo se laminó para «{file}», pero esta impresora es «{ours}». Compruebe que "
        "su G-code inicial y el tamaño de la cama sirven para esta impresora o vuelva a "
        "laminarlo."),
    "temperature_missing": ("block", "limit",
        "Give a target temperature for the extruder, the bed or both.",
        "Indique una temperatura objetivo para el extrusor, la cama o ambos."),
    "temperature_invalid": ("block", "limit",
        "The {heater_en} temperature must be a number of 0 °C or more, not {value}.",
        "La temperatura de {heater_es} debe ser un número igual o mayor que 0 °C, no {value}."),
    "extruder_temp_over_max": ("block", "limit",
        "{temp} °C is above this extruder's maximum of {limit} °C. Choose a lower temperature.",
        "{temp} °C supera el máximo del extrusor de esta impresora ({limit} °C). Elija una "
        "temperatura más baja."),
    "bed_temp_over_max": ("block", "limit",
        "{temp} °C is above this bed's maximum of {limit} °C. Choose a lower temperature.",
        "{temp} °C supera el máximo de la cama de esta impresora ({limit} °C). Elija una "
        "temperatura más baja."),
    "home_axes_invalid": ("block", "limit",
        "Cannot home axes {axes}: give any of x, y and z, for example 'xyz'.",
        "No se puede hacer homing de los ejes {axes}: indique x, y o z, por ejemplo «xyz»."),
    "gcode_empty": ("block", "limit",
        "The G-code script is empty. Type at least one command.",
        "El script de G-code está vacío. Escriba al menos un comando."),
    "gcode_too_long": ("block", "limit",
        "The script is {kib} KiB; the limit is 64 KiB. Upload long G-code as a file and "
        "print it instead.",
        "El script ocupa {kib} KiB y el límite es de 64 KiB. Suba el G-code largo como "
        "archivo e imprímalo."),
    "gcode_m112": ("block", "limit",
        "M112 is not sent as G-code, where it would wait behind other commands. Use the "
        "emergency stop action, which stops the printer at once.",
        "M112 no se envía como G-code, donde esperaría detrás de otros comandos. Use la "
        "acción de parada de emergencia, que detiene la impresora al instante."),
    "gcode_extruder_temp_over_max": ("block", "limit",
        "Line {line} sets the extruder to {temp} °C, above its maximum of {limit} °C. Use a "
        "lower temperature.",
        "La línea {line} pone el extrusor a {temp} °C, por encima de su máximo ({limit} °C). "
        "Use una temperatura más baja."),
    "gcode_bed_temp_over_max": ("block", "limit",
        "Line {line} sets the bed to {temp} °C, above its maximum of {limit} °C. Use a lower "
        "temperature.",
        "La línea {line} pone la cama a {temp} °C, por encima de su máximo ({limit} °C). Use "
        "una temperatura más baja."),
    "gcode_move_outside_volume": ("warn", "limit",
        "Line {line} moves {axis} outside this printer's range ({low}–{high} mm); Klipper "
        "will refuse it and stop the script. Check the coordinates and the G90/G91 mode.",
        "La línea {line} mueve {axis} fuera del rango de esta impresora ({low}–{high} mm); "
        "Klipper la rechazará y detendrá el script. Revise las coordenadas y el modo G90/G91."),
}  # fmt: skip


@dataclass(frozen=True)
class Reason:
    """One finding: a stable code, how serious it is, and what to do, in two languages."""

    code: str
    level: Level
    category: Category
    en: str
    es: str


def reason(code: str, **values: str | float) -> Reason:
    """The catalogued reason ``code`` with its placeholders filled in for each language.

    Numbers are written the way each language writes them; a value named ``*_en`` or
    ``*_es`` is for that language's message only."""
    level, category, en, es = MESSAGES[code]
    return Reason(
        code,
        level,
        category,
        en.format(**{k: v if isinstance(v, str) else _en(v) for k, v in values.items()}),
        es.format(**{k: v if isinstance(v, str) else _es(v) for k, v in values.items()}),
    )


def _en(value: float) -> str:
    return f"{value:g}"


def _es(value: float) -> str:
    # Spanish writes the decimal separator as a comma: 0,4 mm.
    return f"{value:g}".replace(".", ",")
