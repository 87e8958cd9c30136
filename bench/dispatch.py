"""Dispatch decision time: one ``plan()`` round over 5,000 printers and 10,000 queued jobs.

``python -m bench.dispatch [--printers 5000] [--jobs 10000] [--rounds 50] [--seed 1]``

Builds a farm in memory (seeded, so every run sees the same one): 50 rooms of 100 printers
(each room a power group), 8 printer kinds (model, build volume, nozzle, max temperatures),
PLA / PETG / ABS loaded or none recorded, a few tags; 60 % printing (some still heating),
15 % idle and available, the rest awaiting a clear, held, offline or starting. 10,000 jobs,
each its own file (its own sha256, so nothing is shared by file), 1-10 copies, most needing
a material, some tags, a model, a pinned printer, a time to wait for, or earlier failures.
The heating budget is 3 per group, the service's default.

Scenarios, each timed over ``--rounds`` rounds (p50 / p99 / max):

- **baseline**: building the 5,000 :class:`PrinterSnapshot` objects a round starts from
  (what the dispatcher does each round anyway), in this run, so a loaded machine shows here
  too; every other figure is also given as a ratio to its p50.
- **steady**: a round with the :class:`Memo` kept between rounds, as the dispatcher keeps it.
- **cold**: a fresh memo every round (the first round after a start, or a queue of new files).
- **why**: :func:`why` for one job needing a material: a round plus a line per printer
  (``GET /api/jobs/{id}/why``).
- **morning**: every printer idle and available and no heating budget: thousands of
  assignments in one round (the worst case for the planner's work per round), warm and cold.
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any

from kybercore.core.validation import PrinterFacts
from kybercore.jobs.models import Gate, Job, JobFile, Requirements
from kybercore.jobs.rules import Memo, Plan, PrinterSnapshot, plan, why

NOW = datetime(2026, 5, 1, 9, 0, tzinfo=UTC)
BUDGET = 3
# model, build volume, nozzle, max hotend, max bed
KINDS = [
    ("Voron 2.4", (350.0, 350.0, 340.0), 0.4, 300.0, 120.0),
    ("Voron 2.4", (300.0, 300.0, 280.0), 0.6, 300.0, 120.0),
    ("Prusa MK4", (250.0, 210.0, 220.0), 0.4, 290.0, 120.0),
    ("Prusa MK4", (250.0, 210.0, 220.0), 0.6, 290.0, 120.0),
    ("Ender 3", (220.0, 220.0, 250.0), 0.4, 260.0, 100.0),
    ("RatRig V-Core 3", (400.0, 400.0, 400.0), 0.4, 300.0, 120.0),
    ("Bambu X1C", (256.0, 256.0, 256.0), 0.4, 300.0, 110.0),
    ("Prusa MINI", (180.0, 180.0, 180.0), 0.4, 280.0, 100.0),
]
MATERIALS = ["PLA"] * 10 + ["PETG"] * 6 + ["ABS"] * 3 + [None]
TAGS = ["fast", "big", "lab", "night"]
TEMPS = {"PLA": (205.0, 60.0), "PETG": (235.0, 80.0), "ABS": (250.0, 100.0)}


def farm(count: int, rng: random.Random, *, all_free: bool = False) -> list[dict[str, Any]]:
    """Printers as plain data, the way the fleet service holds them."""
    printers = []
    for i in range(count):
        model, volume, nozzle, hot, bed = rng.choice(KINDS)
        roll = rng.random()
        state, gate_state, connection, attempt = "standby", "available", "online", None
        if not all_free:
            if roll < 0.60:
                state, attempt = "printing", i
            elif roll < 0.70:
                state, gate_state, attempt = "complete", "awaiting_clear", i
            elif roll < 0.75:
                gate_state = rng.choice(["held", "maintenance"])
            elif roll < 0.80:
                connection = "offline"
            elif roll < 0.81:
                attempt = i  # a start in progress
        printers.append({
            "id": f"printer-{i:05d}", "model": model, "volume": volume, "nozzle": nozzle,
            "max_hot": hot, "max_bed": bed, "material": rng.choice(MATERIALS),
            "tags": tuple(rng.sample(TAGS, rng.choice([0, 0, 1, 2]))),
            "group": f"room-{i % 50:02d}", "connection": connection, "print_state": state,
            "gate": gate_state, "attempt": attempt,
            "heating": state == "printing" and rng.random() < 0.02,
            "usage": rng.uniform(0, 500_000),
            "last_used": NOW - timedelta(hours=rng.uniform(0, 300)),
        })  # fmt: skip
    return printers


def snapshots(printers: list[dict[str, Any]]) -> list[PrinterSnapshot]:
    """The baseline: the objects a round starts from, built from the fleet's plain data."""
    return [snapshot(p) for p in printers]


def snapshot(p: dict[str, Any]) -> PrinterSnapshot:
    """One printer's snapshot, as the dispatcher builds it."""
    facts = PrinterFacts(
        connection=p["connection"], klippy_state="ready", print_state=p["print_state"],
        model=p["model"], build_volume=p["volume"], nozzle_diameter=p["nozzle"],
        material=p["material"], max_extruder_temp=p["max_hot"], max_bed_temp=p["max_bed"],
    )  # fmt: skip
    return PrinterSnapshot(
        id=p["id"], facts=facts, gate=Gate(p["id"], p["gate"], "", NOW, p["attempt"], "bench"),
        tags=p["tags"], power_group=p["group"], heating=p["heating"],
        usage_seconds=p["usage"], last_used=p["last_used"],
    )  # fmt: skip


def queue(count: int, printer_ids: list[str], rng: random.Random) -> list[Job]:
    """Queued jobs, each with a file of its own."""
    jobs = []
    for jid in range(1, count + 1):
        material = rng.choice(["PLA", "PLA", "PETG", "ABS"])
        extr, bed = TEMPS[material]
        meta = {
            "slicer": "PrusaSlicer", "object_height": round(rng.uniform(5, 300), 1),
            "nozzle_diameter": rng.choice([0.4] * 9 + [0.6]), "filament_type": material,
            "first_layer_extr_temp": extr, "first_layer_bed_temp": bed,
            "estimated_time": rng.randint(600, 40_000),
        }  # fmt: skip
        quantity = rng.randint(1, 10)
        req = Requirements(
            material=material if rng.random() < 0.7 else None,
            tags=tuple(rng.sample(TAGS, 1)) if rng.random() < 0.1 else (),
            model=rng.choice(KINDS)[0] if rng.random() < 0.1 else None,
            printer=rng.choice(printer_ids) if rng.random() < 0.02 else None,
        )
        jobs.append(Job(
            id=jid, file=JobFile(f"{rng.getrandbits(256):064x}", f"part-{jid}.gcode", 1, meta),
            quantity=quantity, priority=rng.choice([0, 0, 0, 1, 2]), position=float(jid),
            not_before=NOW + timedelta(hours=2) if rng.random() < 0.05 else None,
            requirements=req, allow_mismatch=rng.random() < 0.05, max_attempts=3,
            state="queued", reason="", done=0, in_flight=0,
            failures=1 if rng.random() < 0.05 else 0, created_at=NOW, created_by="bench",
        ))  # fmt: skip
    return jobs


def timed(rounds: int, work: Callable[[], object]) -> tuple[list[float], object]:
    """Seconds per call of ``work`` over ``rounds`` calls, and its last result."""
    times, result = [], None
    for _ in range(rounds):
        start = time.perf_counter()
        result = work()
        times.append(time.perf_counter() - start)
    return times, result


def p99(values: list[float]) -> float:
    if len(values) < 2:
        return values[0]
    return statistics.quantiles(values, n=100, method="inclusive")[98]


def row(name: str, times: list[float], base: float, note: str = "") -> None:
    p50 = statistics.median(times)
    print(
        f"{name:<28} p50 {p50 * 1000:8.2f} ms  p99 {p99(times) * 1000:8.2f} ms  "
        f"max {max(times) * 1000:8.2f} ms  = {p50 / base:6.1f}x baseline  {note}"
    )


def main(count: int, jobs_count: int, rounds: int, seed: int) -> None:
    rng = random.Random(seed)
    fleet = farm(count, rng)
    jobs = queue(jobs_count, [p["id"] for p in fleet], rng)
    attempts = {j.id: {fleet[0]["id"]: 1} for j in jobs if j.failures}
    print(f"{count} printers, {jobs_count} queued jobs, heating budget {BUDGET} per group; "
          f"{rounds} rounds each; load average {os.getloadavg()[0]:.2f}\n")  # fmt: skip
    base_times, built = timed(rounds, lambda: snapshots(fleet))
    base = statistics.median(base_times)
    printers: list[PrinterSnapshot] = built  # type: ignore[assignment]
    # Reserved, uploading or starting: an attempt on the printer, nothing printing yet.
    starting = {p["id"] for p in fleet if p["attempt"] is not None and p["gate"] == "available"
                and p["print_state"] == "standby"}  # fmt: skip
    row("baseline: build snapshots", base_times, base)

    def round_with(memo_for: Callable[[], Memo], fleet_now: list[PrinterSnapshot],
                   budget: int | None) -> Callable[[], Plan]:  # fmt: skip
        return lambda: plan(jobs, fleet_now, heating_budget=budget, starting=starting, now=NOW,
                            attempts_per_printer=attempts, memo=memo_for())  # fmt: skip

    kept = Memo()
    plan(jobs, printers, heating_budget=BUDGET, starting=starting, now=NOW, memo=kept)
    for name, memo_for in (("steady (memo kept)", lambda: kept), ("cold (fresh memo)", Memo)):
        times, result = timed(rounds, round_with(memo_for, printers, BUDGET))
        assert isinstance(result, Plan)
        free = sum(p.free for p in printers)
        row(name, times, base, f"{len(result.assignments)} starts, {free} free printers")
    waiting = next(j for j in jobs if j.requirements.material and not j.requirements.printer)
    times, lines = timed(rounds, lambda: why(waiting, printers, queue=jobs, heating_budget=BUDGET,
                                             starting=starting, now=NOW, memo=kept))  # fmt: skip
    row("why (one job, every printer)", times, base, f"{len(lines)} lines")  # type: ignore[arg-type]
    morning = snapshots(farm(count, random.Random(seed), all_free=True))
    starting = set()
    kept = Memo()
    plan(jobs, morning, heating_budget=None, now=NOW, memo=kept)
    for name, memo_for in (("morning, no budget (kept)", lambda: kept), ("morning, cold", Memo)):
        times, result = timed(max(rounds // 5, 3), round_with(memo_for, morning, None))
        assert isinstance(result, Plan)
        row(name, times, base, f"{len(result.assignments)} starts, all {count} free")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--printers", type=int, default=5000)
    parser.add_argument("--jobs", type=int, default=10_000)
    parser.add_argument("--rounds", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    main(args.printers, args.jobs, args.rounds, args.seed)
