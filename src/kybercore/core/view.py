"""The fused view of a printer: its configuration plus its live state, as plain data.

Pure functions only. The fleet service keeps a :class:`LivePrinter` per printer, fed by the
Moonraker session; :func:`fuse` turns config + live state into the JSON-ready dict that
``GET /api/printers`` and the browser WebSocket send, and :func:`diff` finds what changed
between two such dicts so only that goes over the wire.
"""

from __future__ import annotations

import contextlib
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from kybercore.core.numbers import finite_number, rounded
from kybercore.core.progress import BUSY, PrintMemory, estimate, track
from kybercore.core.spools import Spool, SpoolmanState
from kybercore.core.validation import PrinterFacts, allowed_actions
from kybercore.moonraker.objects import Status
from kybercore.registry.models import PrinterConfig

View = dict[str, Any]

LIMITS: tuple[str, ...] = ("build_volume", "nozzle_diameter", "max_extruder_temp", "max_bed_temp")
"""The capabilities validation judges actions by; with all of them in printers.json, Klippy's
configfile is not needed."""


@dataclass
class LivePrinter:
    """What KyberCore knows right now about one printer, from Moonraker."""

    connection: str = "connecting"
    connection_error: str = ""
    klippy_state: str = "disconnected"
    klippy_message: str = ""
    status: Status = field(default_factory=dict)
    file_meta: dict[str, Any] | None = None
    """Metadata of the file in ``print_stats.filename`` (for ETA and thumbnail)."""
    detected: dict[str, Any] = field(default_factory=dict)
    """Capabilities read from Klippy's configfile: build_volume, nozzle_diameter, max temps."""
    limits: str = "loading"
    """Whether ``detected`` is read: ``loading`` (since the last (re)subscription),
    ``known``, or ``unknown`` (the read failed; it is retried)."""
    print_memory: PrintMemory = field(default_factory=PrintMemory)
    """What the view remembers of the print between updates (the fleet keeps it with
    :func:`tracked`); it keeps the progress shown from going backwards."""
    updated_at: float = 0.0
    spool: Spool | None = None
    """The active Spoolman spool, when Moonraker has ``[spoolman]`` and one is set."""
    spoolman: SpoolmanState = "unknown"
    """Why there is a spool or not (see :data:`~kybercore.core.spools.SpoolmanState`)."""
    thumbnail_memo: tuple[dict[str, Any], str, Any] | None = field(
        default=None, repr=False, compare=False
    )
    """(``file_meta`` object, filename, thumbnail) of the last :func:`fuse`."""
    sensors_memo: tuple[Status, int, tuple[str, ...]] | None = field(
        default=None, repr=False, compare=False
    )
    """(``status`` object, its length, its filament sensors' names) of the last
    :func:`fuse`: objects are only ever added to a status, so the same dict at the same
    length has the same names."""
    minimum_memo: tuple[Any, list[float] | None] | None = field(
        default=None, repr=False, compare=False
    )
    """(``toolhead.axis_minimum`` as received, as the view shows it) of the last
    :func:`fuse`: Klipper sends it once, and a delta replaces the list, never edits it."""


def _num(value: Any, digits: int = 1) -> float | None:
    # A finite float (x - x is 0 only then) skips the call: a dozen of these per fuse().
    if type(value) is float and value - value == 0.0:
        return rounded(value, digits)
    number = finite_number(value)
    return None if number is None else rounded(number, digits)


# fuse() runs for every status update of every printer (4 Hz each); dumping the pydantic
# config, merging capabilities and re-deriving the allowed actions were most of its cost. A
# config object is replaced on every edit, never changed in place, and so is
# ``LivePrinter.detected``: what derives from them is kept for as long as they live.
@dataclass
class _ConfigDerived:
    public: View
    configured: dict[str, Any]
    """``config.capabilities`` as JSON data; None where printers.json leaves a value out."""
    all_limits: bool
    """printers.json gives every one of :data:`LIMITS`."""
    detected: dict[str, Any] | None = None
    capabilities: dict[str, Any] = field(default_factory=dict)
    """``configured`` completed from ``detected`` (the object it was computed from)."""
    actions_key: tuple[Any, ...] | None = None
    actions: dict[str, bool] = field(default_factory=dict)
    """:func:`allowed_actions` for the live state in ``actions_key``."""


_derived: dict[int, _ConfigDerived] = {}


def _config_derived(config: PrinterConfig) -> _ConfigDerived:
    key = id(config)
    derived = _derived.get(key)
    if derived is None:
        configured = config.capabilities.model_dump(mode="json")
        derived = _ConfigDerived(
            config.public().model_dump(mode="json"),
            configured,
            all(configured.get(name) is not None for name in LIMITS),
        )
        _derived[key] = derived
        weakref.finalize(config, _derived.pop, key, None)
    return derived


def _actions(
    config: PrinterConfig, live: LivePrinter, caps: dict[str, Any], limits: str
) -> dict[str, bool]:
    """:func:`allowed_actions`, derived again only when an input of :func:`facts` changed
    (printers change state far less often than they report temperatures). ``caps`` and
    ``limits``: :func:`capabilities` and :func:`limits_state`, which fuse() has at hand."""
    derived = _config_derived(config)
    key = (
        caps,
        limits,
        live.connection,
        live.klippy_state,
        live.status.get("print_stats", {}).get("state"),
        live.status.get("toolhead", {}).get("axis_minimum"),
    )
    if derived.actions_key != key:
        derived.actions = allowed_actions(facts(config, live))
        derived.actions_key = key
    return derived.actions


def capabilities(config: PrinterConfig, live: LivePrinter) -> dict[str, Any]:
    """What validation uses: printers.json's values, else what Klippy reports.
    Shared between calls: never modify the result."""
    derived = _config_derived(config)
    if derived.detected is not live.detected:
        derived.capabilities = {
            key: value if value is not None else live.detected.get(key)
            for key, value in derived.configured.items()
        }
        derived.detected = live.detected
    return derived.capabilities


def limits_state(config: PrinterConfig, live: LivePrinter) -> str:
    """``known`` when printers.json gives every limit, else how Klippy's read stands."""
    return "known" if _config_derived(config).all_limits else live.limits


def facts(config: PrinterConfig, live: LivePrinter) -> PrinterFacts:
    """The inputs of :mod:`kybercore.core.validation` for this printer."""
    caps = capabilities(config, live)
    volume = caps.get("build_volume")
    return PrinterFacts(
        connection=live.connection,
        klippy_state=live.klippy_state,
        print_state=str(live.status.get("print_stats", {}).get("state", "")),
        model=config.model,
        build_volume=(volume["x"], volume["y"], volume["z"]) if volume else None,
        axis_minimum=axis_minimum(live.status.get("toolhead", {})),
        nozzle_diameter=caps.get("nozzle_diameter"),
        # The spool on the printer says what is loaded better than printers.json.
        material=(live.spool.material if live.spool and live.spool.material else None)
        or caps.get("material"),
        max_extruder_temp=caps.get("max_extruder_temp"),
        max_bed_temp=caps.get("max_bed_temp"),
        limits=limits_state(config, live),
        filament_left_g=live.spool.remaining_g if live.spool else None,
    )


def facts_of_view(config: PrinterConfig, view: Mapping[str, Any]) -> PrinterFacts:
    """The inputs of :mod:`kybercore.core.validation`, read back from the printer's fused
    view: what :func:`facts` gives for the live state the view was fused from, for a
    process that has the views but not the live state (a front on NATS).

    One field differs: ``print_state`` is the view's ``job.state``, which :func:`fuse`
    blanks while Klippy is not ready, where :func:`facts` keeps ``print_stats.state``.
    Validation gives the same verdicts either way: it reads the print state only once
    Klippy is ready (not ready blocks every action but e-stop and the restarts first).
    """
    caps: Mapping[str, Any] = view.get("capabilities") or {}
    volume = caps.get("build_volume")
    spool: Mapping[str, Any] = view.get("spool") or {}
    minimum = (view.get("toolhead") or {}).get("axis_minimum")
    return PrinterFacts(
        connection=str(view.get("connection", "")),
        klippy_state=str(view.get("klippy_state", "")),
        print_state=str((view.get("job") or {}).get("state", "")),
        model=config.model,
        build_volume=(volume["x"], volume["y"], volume["z"]) if volume else None,
        axis_minimum=axis_minimum({"axis_minimum": minimum}),
        nozzle_diameter=caps.get("nozzle_diameter"),
        # As facts(): the spool on the printer says what is loaded better than printers.json.
        material=spool.get("material") or caps.get("material"),
        max_extruder_temp=caps.get("max_extruder_temp"),
        max_bed_temp=caps.get("max_bed_temp"),
        limits=str(view.get("limits", "unknown")),
        filament_left_g=spool.get("remaining_g") if spool else None,
    )


def axis_minimum(toolhead: Mapping[str, Any]) -> tuple[float, float, float] | None:
    """Klipper's ``toolhead.axis_minimum`` for X, Y and Z; None unless all three are
    numbers (a peer's junk must not reach validation's arithmetic)."""
    minimum = toolhead.get("axis_minimum")
    if not isinstance(minimum, list) or len(minimum) < 3:
        return None
    x, y, z = (finite_number(v) for v in minimum[:3])
    return None if x is None or y is None or z is None else (x, y, z)


def fuse(config: PrinterConfig, live: LivePrinter, *, tracked: bool = False) -> View:
    """The printer as the API and the browser see it. Never contains the API key.
    ``tracked``: ``live.print_memory`` is :func:`tracked` for the current state already
    (the fleet's render stores it just before), so it is not tracked a second time."""
    # Field types are whatever the peer sent: read numbers and text defensively, so one
    # misbehaving printer cannot break the view of the whole fleet.
    status = live.status
    stats = status.get("print_stats", {})
    display = status.get("display_status", {})
    toolhead = status.get("toolhead", {})
    gcode_move = status.get("gcode_move", {})
    info: dict[str, Any] = stats["info"] if isinstance(stats.get("info"), dict) else {}
    print_state = str(stats.get("state", "")) if live.klippy_state == "ready" else ""
    filename = str(stats.get("filename") or "")
    meta = _meta_of(live, filename)
    estimated = _num(meta.get("estimated_time"), 0)
    duration = _num(stats.get("print_duration"), 1) or 0.0
    reckoned = estimate(live.print_memory, status, meta, live.updated_at, tracked=tracked)
    busy = print_state in BUSY
    eta = reckoned.eta_seconds if busy else None
    eta_at = reckoned.eta_at if busy else None
    thumbnail = _thumbnail(live, meta, filename)
    shown_position = _position(toolhead.get("position"))
    # A shallow copy: nested values of the cached dump are shared, and views are never
    # modified once built (the hub diffs them, the API serializes them).
    view: View = dict(_config_derived(config).public)
    view["capabilities"] = caps = capabilities(config, live)
    view["limits"] = limits = limits_state(config, live)
    view.update(
        connection=live.connection,
        connection_error=live.connection_error,
        klippy_state=live.klippy_state,
        klippy_message=live.klippy_message,
        job={
            "state": print_state,
            "filename": filename,
            "progress": rounded(reckoned.progress, 4),
            "eta_seconds": round(eta) if eta is not None else None,
            "eta_at": round(eta_at) if eta_at is not None else None,
            "estimated_time": estimated,
            "print_duration": round(duration),
            "total_duration": round(_num(stats.get("total_duration")) or 0.0),
            "message": str(stats.get("message") or display.get("message") or ""),
            "layer": info.get("current_layer"),
            "total_layers": info.get("total_layer"),
            "thumbnail": thumbnail,
        },
        extruder=_heater(status.get("extruder", {})),
        bed=_heater(status.get("heater_bed", {})),
        toolhead={
            "position": shown_position,
            "homed_axes": str(toolhead.get("homed_axes") or ""),
            # For validation's moves check where only the view is known (facts_of_view).
            "axis_minimum": _shown_minimum(live, toolhead),
        },
        fan_speed=_num(status.get("fan", {}).get("speed"), 2),
        speed_factor=_num(gcode_move.get("speed_factor"), 2),
        extrude_factor=_num(gcode_move.get("extrude_factor"), 2),
        z_offset=_z_offset(gcode_move.get("homing_origin")),
        can_extrude=status.get("extruder", {}).get("can_extrude") is True,
        runout=_runout(live),
        spool=live.spool.public if live.spool else None,
        spoolman=live.spoolman,
        actions=_actions(config, live, caps, limits),
        updated_at=rounded(live.updated_at, 1),
    )
    return view


_SENSORS = ("filament_switch_sensor ", "filament_motion_sensor ")


def filament_runout(status: Status) -> bool:
    """An enabled filament sensor (``[filament_switch_sensor x]``, ``[filament_motion_sensor
    x]``) reports no filament. In the view because notifications read it (a pause for a
    runout says so), also on a front, which has the views but not Klipper's status."""
    # A loop, not any() over a generator: fuse() runs it on every update of every printer.
    for name, fields in status.items():
        if (
            name.startswith(_SENSORS)
            and isinstance(fields, dict)
            and fields.get("enabled", True) is not False
            and fields.get("filament_detected") is False
        ):
            return True
    return False


def _runout(live: LivePrinter) -> bool:
    """:func:`filament_runout` of the live status, over the sensors it names (found once
    per status object and length: the status holds a dozen objects, sensors are rare)."""
    status = live.status
    memo = live.sensors_memo
    if memo is None or memo[0] is not status or memo[1] != len(status):
        names = tuple(name for name in status if name.startswith(_SENSORS))
        live.sensors_memo = memo = (status, len(status), names)
    return bool(memo[2]) and filament_runout({name: status[name] for name in memo[2]})


def _position(position: Any) -> list[float] | None:
    """``toolhead.position`` rounded for the view; None unless every value is a number."""
    if not isinstance(position, list) or not position:
        return None
    for value in position:
        # A loop, not all() over a generator: this runs on every update of every printer.
        if type(value) is not float and not isinstance(value, int | float):
            return None
    return [rounded(float(value), 2) for value in position[:4]]


def _shown_minimum(live: LivePrinter, toolhead: Mapping[str, Any]) -> list[float] | None:
    """:func:`axis_minimum` as the view shows it, worked out once per list received."""
    raw = toolhead.get("axis_minimum")
    memo = live.minimum_memo
    if memo is None or memo[0] is not raw:
        minimum = axis_minimum(toolhead)
        live.minimum_memo = memo = (raw, list(minimum) if minimum else None)
    return memo[1]


def _thumbnail(live: LivePrinter, meta: dict[str, Any], filename: str) -> Any:
    """The largest thumbnail of the file, under gcodes/; worked out once per metadata
    object (the fleet replaces ``file_meta``, never changes it in place)."""
    memo = live.thumbnail_memo
    if memo is not None and memo[0] is meta and memo[1] == filename:
        return memo[2]
    thumbs = [t for t in meta.get("thumbnails") or [] if isinstance(t, dict)]
    thumbnail = (
        max(thumbs, key=lambda t: _num(t.get("width")) or 0).get("relative_path")
        if thumbs
        else None
    )
    if thumbnail and "/" in filename:
        # Moonraker gives it relative to the file's own folder (the queue's uploads live in
        # gcodes/kybercore/); the view says where it is under gcodes/.
        thumbnail = f"{filename.rsplit('/', 1)[0]}/{thumbnail}"
    live.thumbnail_memo = (meta, filename, thumbnail)
    return thumbnail


def _z_offset(origin: Any) -> float | None:
    """The Z babystep: ``gcode_move.homing_origin`` is ``[x, y, z, e]``."""
    if isinstance(origin, list) and len(origin) > 2 and isinstance(origin[2], (int, float)):
        return rounded(float(origin[2]), 3)
    return None


def _meta_of(live: LivePrinter, filename: str) -> dict[str, Any]:
    """The metadata of the file being printed; ``{}`` while unknown."""
    meta = live.file_meta
    return meta if meta and meta.get("filename") == filename else {}


def tracked(live: LivePrinter) -> PrintMemory:
    """``live.print_memory`` after the current status and file metadata: the fleet stores
    it before every :func:`fuse` whose view it publishes."""
    filename = str(live.status.get("print_stats", {}).get("filename") or "")
    return track(live.print_memory, live.status, _meta_of(live, filename))


def _heater(obj: Mapping[str, Any]) -> dict[str, float | None]:
    return {
        "temperature": _num(obj.get("temperature")),
        "target": _num(obj.get("target")),
        "power": _num(obj.get("power"), 2),
    }


_ABSENT: Any = object()
"""Stands for a key missing from the old view: equal to nothing."""


def diff(old: Mapping[str, Any], new: Mapping[str, Any]) -> dict[str, Any]:
    """A patch that turns ``old`` into ``new`` when deep-merged (lists replace).

    Keys never disappear from a view, so a patch only sets; it is empty when nothing changed.
    """
    patch: dict[str, Any] = {}
    for key, value in new.items():
        previous = old.get(key, _ABSENT)
        if value is previous or value == previous:
            # Most of a view is unchanged: one C-level comparison instead of a recursion
            # into each nested dict (capabilities, actions, job, heaters); the parts fuse()
            # reuses (config, capabilities, actions) are the very same objects.
            continue
        if isinstance(value, dict) and isinstance(previous, dict):
            inner = diff(previous, value)
            if inner:
                patch[key] = inner
        else:
            patch[key] = value
    return patch


def detect_capabilities(settings: Mapping[str, Any]) -> dict[str, Any]:
    """Build volume, nozzle and heater limits from Klippy's ``configfile.settings``."""
    detected: dict[str, Any] = {}
    with contextlib.suppress(KeyError, TypeError, ValueError):
        detected["build_volume"] = {
            axis: float(settings[f"stepper_{axis}"]["position_max"]) for axis in ("x", "y", "z")
        }
    extruder = settings.get("extruder", {})
    bed = settings.get("heater_bed", {})
    if "nozzle_diameter" in extruder:
        detected["nozzle_diameter"] = float(extruder["nozzle_diameter"])
    if "max_temp" in extruder:
        detected["max_extruder_temp"] = float(extruder["max_temp"])
    if "max_temp" in bed:
        detected["max_bed_temp"] = float(bed["max_temp"])
    return detected
