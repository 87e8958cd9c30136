"""The objects of the running print, from Klipper's ``exclude_object`` status: what a
printer page draws on the bed and offers to exclude ("cancel object", as in Mainsail).

Pure: the caller queries ``exclude_object`` (never subscribed: it changes a few times per
print, and its polygons are large) and passes the status here. A peer's data may be
anything, so what is not a name, a point or a list of points is left out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

Point = tuple[float, float]


@dataclass(frozen=True, slots=True)
class PrintObject:
    """One object the slicer labelled (``EXCLUDE_OBJECT_DEFINE``), in bed millimetres."""

    name: str
    center: Point | None
    polygon: tuple[Point, ...]


@dataclass(frozen=True, slots=True)
class PrintObjects:
    """The running print's objects; ``available`` is False when Klipper has no
    ``[exclude_object]`` section (then nothing can be excluded)."""

    available: bool
    objects: tuple[PrintObject, ...] = ()
    excluded: tuple[str, ...] = ()
    current: str | None = None


def print_objects_of(status: Mapping[str, Any] | None) -> PrintObjects:
    """Read ``exclude_object``'s status (None: Klipper does not have the object)."""
    if not isinstance(status, Mapping):
        return PrintObjects(available=False)
    objects = []
    for item in _list(status.get("objects")):
        if isinstance(item, Mapping) and _is_name(item.get("name")):
            polygon = tuple(p for p in map(_point, _list(item.get("polygon"))) if p is not None)
            objects.append(PrintObject(item["name"], _point(item.get("center")), polygon))
    excluded = tuple(name for name in _list(status.get("excluded_objects")) if _is_name(name))
    current = status.get("current_object")
    return PrintObjects(True, tuple(objects), excluded, current if _is_name(current) else None)


def _list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else []


def _is_name(value: Any) -> bool:
    """One ``NAME=`` parameter of a G-code line: no space, and no ``;`` (a comment)."""
    return (
        isinstance(value, str)
        and bool(value)
        and ";" not in value
        and not any(c.isspace() for c in value)
    )


def _point(value: Any) -> Point | None:
    if not isinstance(value, list) or len(value) < 2:
        return None
    x, y = value[0], value[1]
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in (x, y)):
        return None
    return (float(x), float(y)) if math.isfinite(x) and math.isfinite(y) else None
