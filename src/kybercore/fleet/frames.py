"""What a browser gets of the printers it does not show, and the frames that carry it.

A browser tells the hub which printers it shows (a page of tiles, one printer's page); it
gets those printers' full views and, for the rest of the fleet, a slim summary: what the
dashboard filters, sorts, counts and announces by (name, tags, location, state, progress,
ETA, alarms, allowed actions), without the parts that change several times a second
(temperatures, positions, fans, durations, ``updated_at``). An idle printer's temperatures
then cost the browsers that do not show it nothing at all.

A tick's delta is encoded at most once per distinct need, never once per client: the full
patches once for every browser that shows the whole fleet, the slim summaries once for all
the others, spliced (bytes, no re-encoding) with the full patches of the changed printers in
their view, encoded once per such set of printers.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

import orjson

from kybercore.registry.models import PrinterPublic

SLIM_KEYS: Final = frozenset(PrinterPublic.model_fields) | {
    # The configuration changes only when edited: it costs a snapshot's bytes, no deltas, and
    # the search, filters, facets and forms read it for every printer.
    "capabilities",
    "limits",
    "connection",
    "connection_error",
    "klippy_state",
    "klippy_message",
    "actions",
    "job",
    # The Spools view maps every printer's spool while no tile is on screen; a spool changes
    # only when one is picked or a print ends.
    "spool",
    "spoolman",
}
"""Top-level view keys of the slim summary."""
SLIM_JOB_KEYS: Final = frozenset(
    {"state", "filename", "progress", "eta_seconds", "eta_at", "message"}
)
"""``job`` keys of the slim summary: the state filter, the sorts by progress and time left,
the "next to finish" header and the finished/failed print notifications read them."""


def slim(view: Mapping[str, Any]) -> dict[str, Any]:
    """The slim summary of a view, or of a patch (the summary of a patch between two views
    is the patch between their summaries); ``{}`` when a patch touches nothing in it."""
    out = {key: value for key, value in view.items() if key in SLIM_KEYS}
    job = out.get("job")
    if isinstance(job, dict):
        job = {key: value for key, value in job.items() if key in SLIM_JOB_KEYS}
        if job:
            out["job"] = job
        else:
            del out["job"]
    return out


class DeltaFrames:
    """One tick's delta frame, as each kind of client gets it."""

    def __init__(self, seq: int, patches: dict[str, Any], removed: list[str]) -> None:
        """``patches``: printer id to full patch (a new printer's patch is its view)."""
        self._head = b'{"type":"delta","seq":%d,"removed":%b,"printers":' % (
            seq,
            orjson.dumps(removed),
        )
        self._patches = patches
        self.removed = removed
        self._summaries: dict[str, dict[str, Any]] | None = None
        self._full: bytes | None = None
        self._slim: bytes | None = None
        self._spliced: dict[frozenset[str], bytes] = {}
        self.encodings = 0
        """How many times patches were encoded (the tests and benches read it)."""

    def summaries(self) -> dict[str, dict[str, Any]]:
        """The slim patches of the changed printers whose summary changed (made once)."""
        if self._summaries is None:
            self._summaries = {i: s for i, patch in self._patches.items() if (s := slim(patch))}
        return self._summaries

    def frame(self, view: frozenset[str] | None) -> bytes:
        """The frame for a client showing ``view`` in full (None: every printer).

        A client with a view gets ``printers`` (slim patches of every changed printer) and
        ``full`` (full patches of the changed printers it shows), applied in that order.
        """
        patches = self._patches
        if view is None:
            if self._full is None:
                self._full = self._head + orjson.dumps(patches) + b"}"
                self.encodings += 1
            return self._full
        # Iterate the smaller side: a view is a page of tiles, a tick may touch the fleet.
        if len(view) <= len(patches):
            shown = frozenset(i for i in view if i in patches)
        else:
            shown = frozenset(i for i in patches if i in view)
        frame = self._spliced.get(shown)
        if frame is None:
            if self._slim is None:
                self._slim = orjson.dumps(self.summaries())
                self.encodings += 1
            full = orjson.dumps({i: patches[i] for i in shown}) if shown else b"{}"
            frame = self._head + self._slim + b',"full":' + full + b"}"
            self._spliced[shown] = frame
        return frame


def snapshot_frame(seq: int, printers: bytes, full: list[dict[str, Any]] | None = None) -> bytes:
    """A snapshot: ``printers`` is a JSON array of views (or of slim summaries, then
    ``full`` lists the full views of the printers in the client's view)."""
    head = b'{"type":"snapshot","seq":%d,"printers":' % seq
    if full is None:
        return head + printers + b"}"
    return head + printers + b',"full":' + orjson.dumps(full) + b"}"


def views_frame(views: list[dict[str, Any]]) -> bytes:
    """Full views of printers that entered a client's view: they replace its summaries."""
    return orjson.dumps({"type": "views", "printers": views})
