"""Printers to slots, slots to workers. Pure.

A printer's slot is ``crc32(id) % S``: the same in every process and every run (Python's
``hash`` of a string is salted per process). Workers own slots, never single printers, so
ownership changes hands S keys at a time however large the fleet.
"""

from __future__ import annotations

import math
import zlib
from typing import Final

DEFAULT_SLOTS: Final = 64


def slot_of(printer_id: str, slots: int = DEFAULT_SLOTS) -> int:
    """The slot that holds ``printer_id``."""
    return zlib.crc32(printer_id.encode()) % slots


def fair_share(slots: int, workers: int) -> int:
    """How many slots one of ``workers`` live workers should own (rounded up, so every slot
    has room; a worker above its share releases the rest)."""
    return math.ceil(slots / max(workers, 1))


def slot_key(slot: int) -> str:
    """The slot's key in the leases bucket."""
    return f"s{slot}"
