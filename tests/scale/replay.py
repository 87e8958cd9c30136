"""Replaying the workers' own/drop logs: per slot, no two workers' ownership overlaps."""

from __future__ import annotations

import itertools
import json
from pathlib import Path


def no_overlap(logs: list[Path], died: dict[str, float] | None = None) -> None:
    """Replay own/drop logs: per slot, no two workers' intervals overlap. A worker killed
    (``died``: name → wall time) writes no drops: what it held ends when it died."""
    intervals: dict[str, list[tuple[float, float, str]]] = {}
    for path in logs:
        opened: dict[str, tuple[float, str]] = {}
        for line in path.read_text().splitlines() if path.exists() else []:
            event = json.loads(line)
            key = event["key"]  # a slot of a site
            if event["ev"] == "own":
                opened[key] = (event["t"], event["worker"])
            else:
                start, worker = opened.pop(key)
                intervals.setdefault(key, []).append((start, event["t"], worker))
        for slot, (start, worker) in opened.items():
            end = (died or {}).get(worker, float("inf"))
            intervals.setdefault(slot, []).append((start, end, worker))
    for slot, spans in intervals.items():
        spans.sort()
        for (_, end, who), (start, _, other) in itertools.pairwise(spans):
            overlap = f"slot {slot}: {who} until {end}, {other} from {start}"
            assert who == other or end <= start, overlap
