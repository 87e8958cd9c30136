"""The state changes a stopping ledger could not write (its database did not answer), kept
in a file beside the process's other data and written at its next start.

The jobs heard meanwhile need no such file: they come back from each printer's Moonraker
history. The state changes exist only in the process that saw them. The file is replaced
whole (:func:`~kybercore.files.replace_file`), and removed only once its changes are in the
database.
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path
from typing import Any, Final

from kybercore.files import replace_file
from kybercore.ledger.timeline import STATES, Change, Timeline

log = logging.getLogger(__name__)

VERSION: Final = 1

UNWRITTEN: Final = "ledger-unwritten.json"
"""The file's name in a process's data folder (beside printers.json, or a worker's)."""


def save(path: Path, timeline: Timeline) -> None:
    """Write what ``timeline`` could not (blocking: run it in a thread). Raises OSError."""
    changes, opened = timeline.unwritten()
    changed = [[c.printer, c.state, c.at] for c in changes]
    body = json.dumps({"version": VERSION, "changes": changed, "opened": opened})
    replace_file(path, body.encode())


def load(path: Path) -> tuple[list[Change], dict[str, float]] | None:
    """What a previous run left in ``path`` (blocking: run it in a thread); None when there
    is no file. A file that is not one of these is set aside as ``<name>.bad``, said in
    the log, and None returned: a start is not refused for the history of a previous run."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    try:
        return _parse(json.loads(text))
    except (ValueError, TypeError, KeyError) as exc:
        bad = path.with_name(path.name + ".bad")
        os.replace(path, bad)
        log.warning(
            "%s is not a list of unwritten state changes (%s); set aside as %s, its changes "
            "are not in the timeline",
            path, exc, bad,
        )  # fmt: skip
        return None


def _parse(data: Any) -> tuple[list[Change], dict[str, float]]:
    if not isinstance(data, dict) or data.get("version") != VERSION:
        raise ValueError(f"expected version {VERSION}")
    changes = []
    for printer, state, at in data["changes"]:
        if not isinstance(printer, str) or (state is not None and state not in STATES):
            raise ValueError(f"not a state change: {[printer, state, at]!r}")
        changes.append(Change(printer, state, _time(at)))
    opened = {str(printer): _time(at) for printer, at in dict(data["opened"]).items()}
    return changes, opened


def _time(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"not a time: {value!r}")
    return float(value)
