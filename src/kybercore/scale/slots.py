"""Printers to slots, slots to workers. Pure.

A printer's slot is ``crc32(id) % S``: the same in every process and every run (Python's
``hash`` of a string is salted per process). Workers own slots, never single printers, so
ownership changes hands S keys at a time however large the fleet.

A farm spread over sites (buildings, towns) gives each printer a ``site``: every site has
its own S slots, held only by the workers started for it (``kybercore ingest --site``), so a
printer is connected from its own site's network. The printers without a site form the
default site, held by the workers started without one.
"""

from __future__ import annotations

import math
import zlib
from typing import Final, NamedTuple

DEFAULT_SLOTS: Final = 64
DEFAULT_SITE: Final = ""
DEFAULT_SITE_MARK: Final = "_"
"""The default site in a subject or a key (not a valid site name: those start with a
letter or digit)."""


class SlotRef(NamedTuple):
    """One slot of one site, as a front (which follows every site) names it."""

    site: str
    slot: int


def slot_of(printer_id: str, slots: int = DEFAULT_SLOTS) -> int:
    """The slot that holds ``printer_id`` (within its site)."""
    return zlib.crc32(printer_id.encode()) % slots


def fair_share(slots: int, workers: int) -> int:
    """How many slots one of ``workers`` live workers should own (rounded up, so every slot
    has room; a worker above its share releases the rest)."""
    return math.ceil(slots / max(workers, 1))


def slot_key(slot: int, site: str = DEFAULT_SITE) -> str:
    """The slot's key in the leases bucket: ``s<n>``, ``<site>.s<n>`` for a named site."""
    return f"{site}.s{slot}" if site else f"s{slot}"


def site_token(site: str) -> str:
    """The site as one token of a subject or key (the default site has a name of its own)."""
    return site or DEFAULT_SITE_MARK


def site_of_token(token: str) -> str:
    """The site a :func:`site_token` names."""
    return DEFAULT_SITE if token == DEFAULT_SITE_MARK else token
