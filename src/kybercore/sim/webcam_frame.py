"""What a virtual printer's webcam shows: its bed from above, drawn from Moonraker's status.

No I/O here: :func:`status_from_query` turns one ``/printer/objects/query`` answer (and the
file's metadata) into a :class:`CameraStatus`, and :func:`render_jpeg` draws it. The server
around them is :mod:`kybercore.sim.webcam`.
"""

from __future__ import annotations

import functools
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

from PIL import Image, ImageDraw, ImageFont

WIDTH: Final = 640
HEIGHT: Final = 480
JPEG_QUALITY: Final = 70

# The objects the camera asks its Moonraker for (the query string of objects/query).
QUERY: Final = (
    "print_stats&virtual_sdcard&display_status&webhooks=state,state_message"
    "&toolhead=position,axis_minimum,axis_maximum"
)

_BACKGROUND: Final = (24, 26, 30)
_BED: Final = (58, 62, 70)
_GRID: Final = (72, 77, 88)
_TEXT: Final = (235, 235, 235)
_MUTED: Final = (150, 155, 165)
# The part's colour tells the state at a glance, as the dashboard's pills do.
PART_COLOURS: Final[Mapping[str, tuple[int, int, int]]] = {
    "printing": (255, 140, 30),
    "paused": (240, 200, 40),
    "complete": (80, 200, 120),
    "cancelled": (220, 70, 60),
    "error": (220, 70, 60),
}
_DIM_PART: Final = (110, 110, 115)
_BED_BOX: Final = (20, 60, 400, 440)  # left, top, right, bottom of the bed's drawing area
_PANEL_X: Final = 420


@dataclass(frozen=True)
class CameraStatus:
    """What the camera needs to know about its printer, from one query."""

    state: str
    """print_stats' state (standby, printing, paused, complete, cancelled, error), Klippy's
    state when it is not ready (startup, shutdown, error), or ``offline``."""
    progress: float = 0.0
    filename: str = ""
    layer: int | None = None
    total_layers: int | None = None
    nozzle: tuple[float, float] | None = None
    bed: tuple[float, float, float, float] = (0.0, 0.0, 220.0, 220.0)
    """min x, min y, max x, max y in mm."""
    message: str = ""


CONNECTING: Final = CameraStatus("offline", message="Connecting to Moonraker…")


def _num(value: Any, default: float = 0.0) -> float:
    return float(value) if isinstance(value, int | float) else default


def _layers(
    print_stats: Mapping[str, Any], z: float | None, meta: Mapping[str, Any]
) -> tuple[int | None, int | None]:
    """Current and total layer: Klipper's SET_PRINT_STATS_INFO when the file sets it, else
    estimated from the nozzle height and the slicer's layer heights, as Mainsail does."""
    info = print_stats.get("info") or {}
    current, total = info.get("current_layer"), info.get("total_layer")
    if isinstance(current, int) and isinstance(total, int):
        return current, total
    height = _num(meta.get("layer_height"))
    first = _num(meta.get("first_layer_height"), height)
    top = _num(meta.get("object_height"))
    if height <= 0 or top <= 0:
        return None, None
    # Rounded first: 0.8 / 0.2 is 4.000000000000001, which must not ceil to a layer more.
    total = max(1, math.ceil(round((top - first) / height + 1, 6)))
    if z is None:
        return None, total
    return min(total, max(0, math.ceil(round((z - first) / height + 1, 6)))), total


def _ended_progress(
    print_stats: Mapping[str, Any], meta: Mapping[str, Any], previous: CameraStatus
) -> float:
    """How far a cancelled or failed print got: Klipper forgets its file position then, but
    the part stays on the bed. The last progress seen, else the share of filament used."""
    if previous.filename == print_stats.get("filename") and previous.progress > 0:
        return previous.progress
    total = _num(meta.get("filament_total"))
    return _num(print_stats.get("filament_used")) / total if total > 0 else 0.0


def status_from_query(
    status: Mapping[str, Any], meta: Mapping[str, Any], previous: CameraStatus = CONNECTING
) -> CameraStatus:
    """A camera status from objects/query's ``status``, the printed file's metadata and the
    status before it."""
    webhooks = status.get("webhooks") or {}
    print_stats = status.get("print_stats") or {}
    toolhead = status.get("toolhead") or {}
    klippy = str(webhooks.get("state", "ready"))
    state = str(print_stats.get("state", "standby")) if klippy == "ready" else klippy
    # The file position moves smoothly; a slicer's M73 moves in steps: prefer the former.
    progress = _num((status.get("virtual_sdcard") or {}).get("progress"))
    if progress <= 0:
        progress = _num((status.get("display_status") or {}).get("progress"))
    if state == "complete":
        progress = 1.0
    elif state in ("cancelled", "error") and progress <= 0:
        progress = _ended_progress(print_stats, meta, previous)
    position = toolhead.get("position")
    lows, highs = toolhead.get("axis_minimum"), toolhead.get("axis_maximum")
    bed = CameraStatus("").bed
    if isinstance(lows, list) and isinstance(highs, list) and min(len(lows), len(highs)) >= 2:
        bed = (_num(lows[0]), _num(lows[1]), _num(highs[0], 220.0), _num(highs[1], 220.0))
    nozzle = z = None
    if isinstance(position, list) and len(position) >= 3:
        nozzle, z = (_num(position[0]), _num(position[1])), _num(position[2])
    filename = str(print_stats.get("filename") or "")
    layer, total = _layers(print_stats, z, meta) if filename else (None, None)
    # Klippy says "Printer is ready" when it is: only its trouble is news.
    raw = webhooks.get("state_message") if klippy != "ready" else print_stats.get("message")
    message = str(raw or "").strip()
    return CameraStatus(
        state=state,
        progress=min(1.0, max(0.0, progress)),
        filename=filename,
        layer=layer,
        total_layers=total,
        nozzle=nozzle,
        bed=bed,
        message=message.splitlines()[0] if message else "",
    )


@functools.cache
def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    # Pillow's bundled font (FreeType when built with it): no system font to depend on.
    # Loaded once per size: it is decoded from Pillow's own data each time otherwise.
    return ImageFont.load_default(size)


def _fit(draw: ImageDraw.ImageDraw, text: str, font: Any, width: float) -> str:
    """``text``, cut at the start with an ellipsis until it fits: a file's end tells it apart."""
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength("…" + text, font=font) > width:
        text = text[1:]
    return "…" + text


def _draw_bed(draw: ImageDraw.ImageDraw, status: CameraStatus) -> None:
    min_x, min_y, max_x, max_y = status.bed
    size_x, size_y = max(max_x - min_x, 1.0), max(max_y - min_y, 1.0)
    left, top, right, bottom = _BED_BOX
    scale = min((right - left) / size_x, (bottom - top) / size_y)
    x0 = left + ((right - left) - size_x * scale) / 2
    y1 = bottom - ((bottom - top) - size_y * scale) / 2  # y grows away from the viewer

    def to_px(x: float, y: float) -> tuple[float, float]:
        return x0 + (x - min_x) * scale, y1 - (y - min_y) * scale

    draw.rectangle((*to_px(min_x, max_y), *to_px(max_x, min_y)), fill=_BED)
    for mm in range(50, int(size_x), 50):
        draw.line((*to_px(min_x + mm, min_y), *to_px(min_x + mm, max_y)), fill=_GRID)
    for mm in range(50, int(size_y), 50):
        draw.line((*to_px(min_x, min_y + mm), *to_px(max_x, min_y + mm)), fill=_GRID)
    if status.filename and status.progress > 0:
        # The part: a disc whose area grows with progress, in the state's colour.
        cx, cy = to_px(min_x + size_x / 2, min_y + size_y / 2)
        radius = max(3.0, 0.3 * min(size_x, size_y) * scale * math.sqrt(status.progress))
        colour = PART_COLOURS.get(status.state, _DIM_PART)
        draw.ellipse((cx - radius, cy - radius, cx + radius, cy + radius), fill=colour)
    if status.nozzle is not None:
        nx, ny = to_px(*status.nozzle)
        draw.ellipse((nx - 6, ny - 6, nx + 6, ny + 6), outline=_TEXT, width=2)
        draw.line((nx - 11, ny, nx + 11, ny), fill=_TEXT)
        draw.line((nx, ny - 11, nx, ny + 11), fill=_TEXT)


def _draw_panel(draw: ImageDraw.ImageDraw, status: CameraStatus) -> None:
    big, small = _font(26), _font(18)
    width = WIDTH - _PANEL_X - 20
    colour = PART_COLOURS.get(status.state, _TEXT)
    draw.text((_PANEL_X, 70), status.state.upper(), fill=colour, font=big)
    layer = "—" if status.layer is None else str(status.layer)
    total = "" if status.total_layers is None else f" / {status.total_layers}"
    lines = [f"Progress {status.progress * 100:.0f} %", f"Layer {layer}{total}"]
    if status.filename:
        lines.append(_fit(draw, status.filename, small, width))
    if status.message:
        lines.append(_fit(draw, status.message, small, width))
    for index, line in enumerate(lines):
        draw.text((_PANEL_X, 120 + 30 * index), line, fill=_MUTED, font=small)
    bar_top = 400
    draw.rectangle((_PANEL_X, bar_top, WIDTH - 20, bar_top + 16), outline=_MUTED)
    if status.progress > 0:
        filled = _PANEL_X + (width * status.progress)
        draw.rectangle((_PANEL_X, bar_top, filled, bar_top + 16), fill=colour)


def render_jpeg(name: str, status: CameraStatus, clock: str) -> bytes:
    """One 640×480 JPEG frame: the printer's name, the time (as a camera's overlay), its bed
    from above with the part and the nozzle, and its state, progress and layer."""
    image = Image.new("RGB", (WIDTH, HEIGHT), _BACKGROUND)
    draw = ImageDraw.Draw(image)
    draw.text((20, 16), _fit(draw, name, _font(26), 440), fill=_TEXT, font=_font(26))
    clock_font = _font(18)
    draw.text((WIDTH - 20 - draw.textlength(clock, font=clock_font), 22), clock,
              fill=_MUTED, font=clock_font)  # fmt: skip
    _draw_bed(draw, status)
    _draw_panel(draw, status)
    out = io.BytesIO()
    image.save(out, "JPEG", quality=JPEG_QUALITY)
    return out.getvalue()
