"""The queue's pure rules: eligibility, ranking, the heating budget, one round, its order.

Every rule is shown on both sides (a printer that takes the job, one that does not), and a
hypothesis property test checks a whole round over random fleets and queues. The builders
here (``printer``, ``job``) are shared with test_why.py.
"""

from __future__ import annotations

import ast
import random
from collections import Counter
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kybercore.core.validation import PrinterFacts, validate
from kybercore.jobs.eligibility import normal_tags, problem
from kybercore.jobs.models import Gate, Job, JobFile, Requirements
from kybercore.jobs.rules import Memo, Plan, PrinterSnapshot, plan

NOW = datetime(2026, 5, 1, 14, 30, tzinfo=UTC)
META: dict[str, Any] = {
    "slicer": "PrusaSlicer",
    "object_height": 30.0,
    "nozzle_diameter": 0.4,
    "filament_type": "PLA",
    "first_layer_extr_temp": 205.0,
    "first_layer_bed_temp": 60.0,
    "estimated_time": 136,
}
FACTS = PrinterFacts(
    connection="online",
    klippy_state="ready",
    print_state="standby",
    model="Voron 2.4",
    build_volume=(250.0, 250.0, 230.0),
    nozzle_diameter=0.4,
    material="PLA",
    max_extruder_temp=300.0,
    max_bed_temp=120.0,
)


def gate(printer: str, state: str = "available", **kw: Any) -> Gate:
    fields: dict[str, Any] = {"reason": "", "since": NOW - timedelta(minutes=30),
                              "attempt_id": None, "user": "op"}  # fmt: skip
    return Gate(printer, state, **{**fields, **kw})  # type: ignore[arg-type]


def printer(
    pid: str,
    *,
    gate_state: str = "available",
    attempt_id: int | None = None,
    tags: tuple[str, ...] = (),
    group: str = "A",
    heating: bool = False,
    usage: float = 0.0,
    last_used: datetime | None = None,
    **facts: Any,
) -> PrinterSnapshot:
    return PrinterSnapshot(
        id=pid,
        facts=replace(FACTS, **facts),
        gate=gate(pid, gate_state, attempt_id=attempt_id),
        tags=tags,
        power_group=group,
        heating=heating,
        usage_seconds=usage,
        last_used=last_used,
    )


def job(
    jid: int,
    *,
    quantity: int = 1,
    done: int = 0,
    in_flight: int = 0,
    priority: int = 0,
    position: float | None = None,
    meta: dict[str, Any] | None = None,
    sha: str | None = None,
    req: Requirements | None = None,
    allow: bool = False,
    not_before: datetime | None = None,
    failures: int = 0,
    state: str = "queued",
    reason: str = "",
) -> Job:
    file = JobFile(sha or f"{jid:064x}", f"part-{jid}.gcode", 1000, META if meta is None else meta)
    return Job(
        id=jid, file=file, quantity=quantity, priority=priority,
        position=float(jid) if position is None else position, not_before=not_before,
        requirements=req or Requirements(), allow_mismatch=allow, max_attempts=3,
        state=state, reason=reason, done=done, in_flight=in_flight, awaiting_clear=0,  # type: ignore[arg-type]
        failures=failures, created_at=NOW, created_by="op",
    )  # fmt: skip


def run(jobs: list[Job], printers: list[PrinterSnapshot], **kw: Any) -> Plan:
    options: dict[str, Any] = {"heating_budget": None, "now": NOW, **kw}
    return plan(jobs, printers, **options)


def pairs(result: Plan) -> list[tuple[int, str]]:
    return [(a.job_id, a.printer) for a in result.assignments]


# --- the printer's state ---------------------------------------------------------------------


@pytest.mark.parametrize("state", ["standby", "complete", "cancelled", "error"])
def test_an_idle_printer_takes_a_job(state: str) -> None:
    assert pairs(run([job(1)], [printer("p1", print_state=state)])) == [(1, "p1")]


@pytest.mark.parametrize(
    "snapshot",
    [
        printer("p1", connection="offline"),
        printer("p1", connection="connecting"),
        printer("p1", connection="disabled"),
        printer("p1", connection="auth_failed"),
        printer("p1", klippy_state="startup"),
        printer("p1", klippy_state="shutdown"),
        printer("p1", print_state="printing"),
        printer("p1", print_state="paused"),
        printer("p1", print_state=""),  # not known yet: never guessed idle
        printer("p1", attempt_id=7),  # a start of the queue's in progress
        printer("p1", gate_state="awaiting_clear", attempt_id=7),
        printer("p1", gate_state="held"),
        printer("p1", gate_state="maintenance"),
    ],
    ids=lambda p: (
        f"{p.facts.connection}-{p.facts.klippy_state}-{p.facts.print_state or '?'}"
        f"-{p.gate.state}-{p.gate.attempt_id}"
    ),
)
def test_a_printer_that_is_not_free_takes_nothing(snapshot: PrinterSnapshot) -> None:
    assert not snapshot.free
    assert run([job(1)], [snapshot]).assignments == []


# --- requirements ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("req", "facts", "tags", "takes"),
    [
        (Requirements(material="pla"), {"material": "PLA"}, (), True),
        (Requirements(material="PLA "), {"material": "pla"}, (), True),
        (Requirements(material="PLA"), {"material": "PETG"}, (), False),
        (Requirements(material="PLA"), {"material": None}, (), False),
        (Requirements(nozzle=0.4), {"nozzle_diameter": 0.405}, (), True),
        (Requirements(nozzle=0.4), {"nozzle_diameter": 0.6}, (), False),
        (Requirements(nozzle=0.4), {"nozzle_diameter": None}, (), False),
        (Requirements(model="voron 2.4"), {"model": "Voron 2.4"}, (), True),
        (Requirements(model="Voron2.4"), {"model": "VORON 2.4"}, (), True),
        (Requirements(model="Prusa MK4"), {"model": "Voron 2.4"}, (), False),
        (Requirements(tags=("Room-B", "fast")), {}, ("fast", "room-b", "x"), True),
        (Requirements(tags=("room-b", "fast")), {}, ("room-b",), False),
    ],
)
def test_requirements(
    req: Requirements, facts: dict[str, Any], tags: tuple[str, ...], takes: bool
) -> None:
    # The file's own metadata says nothing that could refuse these printers.
    result = run([job(1, req=req, meta={"slicer": "x"})], [printer("p1", tags=tags, **facts)])
    assert bool(result.assignments) is takes


def test_a_pinned_job_goes_only_to_its_printer() -> None:
    fleet = [printer("p1"), printer("p2", usage=9e9), printer("p3")]
    pinned = job(1, quantity=3, req=Requirements(printer="p2"))
    assert pairs(run([pinned], fleet)) == [(1, "p2")]
    assert run([pinned], [printer("p1")]).assignments == []
    assert run([pinned], [printer("p2", print_state="printing")]).assignments == []


# --- validation of the file --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("meta", "facts"),
    [
        ({**META, "object_height": 240.0}, {}),  # taller than the Z travel
        ({**META, "nozzle_diameter": 0.6}, {}),  # sliced for another nozzle
        ({**META, "first_layer_extr_temp": 320.0}, {}),  # over the hotend's max
        ({**META, "first_layer_bed_temp": 130.0}, {}),  # over the bed's max
        (META, {"limits": "loading"}),  # the limits are not read yet
    ],
)
def test_a_blocking_verdict_never_dispatches(meta: dict[str, Any], facts: dict[str, Any]) -> None:
    printers = [printer("p1", **facts)]
    assert run([job(1, meta=meta)], printers).assignments == []
    assert run([job(1, meta=meta, allow=True)], printers).assignments == []


@pytest.mark.parametrize(
    ("meta", "facts", "code"),
    [
        ({**META, "filament_type": "PETG"}, {}, "filament_mismatch"),
        ({**META, "printer_model": "Prusa MK4"}, {}, "printer_model_mismatch"),
        ({}, {}, "file_metadata_missing"),  # the parser found nothing
    ],
)
def test_a_mismatch_dispatches_only_when_the_job_allows_it(
    meta: dict[str, Any], facts: dict[str, Any], code: str
) -> None:
    printers = [printer("p1", **facts)]
    assert run([job(1, meta=meta)], printers).assignments == []
    (assigned,) = run([job(1, meta=meta, allow=True)], printers).assignments
    assert [w.split(":")[0] for w in assigned.warnings] == [code]


def test_a_job_needing_more_filament_than_the_spool_has_goes_to_a_fuller_one() -> None:
    # Issue 19: a job needing 40 g is not sent to a printer with 25 g left, even the least
    # worn one, nor when the job allows a mismatch (it would run out mid-print).
    meta = {**META, "filament_weight_total": 40.0}
    short = printer("short", filament_left_g=25.0)
    full = printer("full", filament_left_g=500.0, usage=3600.0)
    assert pairs(run([job(1, meta=meta)], [short, full])) == [(1, "full")]
    assert run([job(1, meta=meta, allow=True)], [short]).assignments == []
    # Moonraker's per-extruder weights count when the total is missing.
    per_tool = {**META, "filament_weights": [20.0, 20.0]}
    assert run([job(1, meta=per_tool)], [short]).assignments == []
    # No spool known: nothing is guessed, the weight does not refuse it.
    assert pairs(run([job(1, meta=meta)], [printer("p1")])) == [(1, "p1")]


def test_the_spools_material_is_the_loaded_one_a_job_requires() -> None:
    # facts() takes the spool's material over printers.json's: a PETG spool on a printer
    # recorded as PLA refuses a job requiring PLA.
    req = Requirements(material="PLA")
    assert run([job(1, req=req)], [printer("p1", material="PETG")]).assignments == []
    assert pairs(run([job(1, req=req)], [printer("p1", material="pla")])) == [(1, "p1")]


def test_a_compatible_start_carries_no_warning() -> None:
    (assigned,) = run([job(1)], [printer("p1")]).assignments
    assert assigned.warnings == ()


# --- ranking -----------------------------------------------------------------------------------


def test_the_least_worn_printer_goes_first() -> None:
    earlier, later = NOW - timedelta(days=2), NOW - timedelta(hours=1)
    fleet = [
        printer("a", usage=100.0, last_used=earlier),
        printer("b", usage=50.0, last_used=later),
        printer("c", usage=50.0, last_used=earlier),  # same time, used longer ago than b
        printer("e", usage=50.0),  # never used: before any used one
        printer("d", usage=50.0),
        printer("f", usage=10.0, last_used=later),  # least print time wins over all
    ]
    result = run([job(1, quantity=6)], fleet)
    assert [p for _, p in pairs(result)] == ["f", "d", "e", "c", "b", "a"]


def test_the_wear_order_holds_across_kinds_of_printers_and_across_jobs() -> None:
    # a and c judge alike (PLA), b and d too (PETG): the order interleaves the two kinds.
    fleet = [printer("a"), printer("b", usage=1.0, material="PETG"),
             printer("c", usage=2.0), printer("d", usage=3.0, material="PETG")]  # fmt: skip
    any_file = {"slicer": "x"}
    jobs = [job(1, meta=any_file), job(2, quantity=2, meta=any_file), job(3, meta=any_file)]
    assert pairs(run(jobs, fleet)) == [(1, "a"), (2, "b"), (2, "c"), (3, "d")]


def test_a_printer_one_file_refuses_stays_for_the_next_job() -> None:
    fleet = [printer("pla"), printer("petg", usage=1.0, material="PETG")]
    petg_file = job(1, meta={**META, "filament_type": "PETG"})
    assert pairs(run([petg_file, job(2)], fleet)) == [(1, "petg"), (2, "pla")]


def test_a_retried_job_goes_to_the_printers_that_ran_it_least() -> None:
    fleet = [printer("a"), printer("b", usage=500.0), printer("c", usage=900.0)]
    attempts = {1: {"a": 2, "b": 1}}
    failed = job(1, quantity=2, failures=3)
    assert pairs(run([failed], fleet, attempts_per_printer=attempts)) == [(1, "c"), (1, "b")]
    # Without failures the counts do not matter: wear decides.
    fresh = job(1, quantity=2)
    assert pairs(run([fresh], fleet, attempts_per_printer=attempts)) == [(1, "a"), (1, "b")]


def test_a_retried_job_still_skips_printers_that_cannot_take_it() -> None:
    fleet = [printer("a"), printer("b", material="PETG"), printer("c", print_state="printing")]
    failed = job(1, quantity=3, failures=1, req=Requirements(material="PLA"))
    result = run([failed], fleet, attempts_per_printer={1: {"a": 5}})
    assert pairs(result) == [(1, "a")]


# --- the round ---------------------------------------------------------------------------------


def test_jobs_go_in_priority_then_position_then_id_order() -> None:
    jobs = [
        job(1, position=5.0),
        job(2, priority=1, position=9.0),
        job(3, position=1.0),
        job(4, position=1.0),
        job(5, priority=-1, position=0.0),
    ]
    fleet = [printer(f"p{i}", usage=float(i)) for i in range(5)]
    assert pairs(run(jobs, fleet)) == [(2, "p0"), (3, "p1"), (4, "p2"), (1, "p3"), (5, "p4")]


def test_a_job_gets_at_most_the_copies_it_has_left() -> None:
    fleet = [printer(f"p{i}") for i in range(10)]
    result = run([job(1, quantity=5, done=1, in_flight=2), job(2, quantity=2)], fleet)
    assert Counter(j for j, _ in pairs(result)) == {1: 2, 2: 2}


def test_each_printer_gets_one_assignment_and_the_rest_wait() -> None:
    result = run([job(1, quantity=3), job(2, quantity=3)], [printer("p1"), printer("p2")])
    assert pairs(result) == [(1, "p1"), (1, "p2")]


def test_jobs_not_queued_or_with_nothing_left_are_skipped() -> None:
    jobs = [
        job(1, state="blocked"), job(2, state="done"), job(3, state="cancelled"),
        job(4, quantity=2, done=1, in_flight=1), job(5),
    ]  # fmt: skip
    assert pairs(run(jobs, [printer("p1"), printer("p2")])) == [(5, "p1")]


def test_a_job_not_before_a_future_time_waits_with_a_line() -> None:
    later = NOW + timedelta(minutes=30)
    result = run([job(1, not_before=later), job(2, not_before=NOW)], [printer("p1")])
    assert pairs(result) == [(2, "p1")]
    assert [(w.code, w.en) for w in result.waiting[1]] == [("not_before", "waits until 15:00")]


def test_a_paused_queue_holds_every_job() -> None:
    result = run([job(1), job(2), job(3, state="done")], [printer("p1")], paused=True)
    assert result.assignments == []
    assert {j: [w.code for w in lines] for j, lines in result.waiting.items()} == {
        1: ["queue_paused"], 2: ["queue_paused"],
    }  # fmt: skip


def test_a_job_no_printer_fits_does_not_stop_the_jobs_after_it() -> None:
    jobs = [job(1, req=Requirements(material="ABS")), job(2, meta={**META, "object_height": 999})]
    jobs.append(job(3))
    assert pairs(run(jobs, [printer("p1")])) == [(3, "p1")]


# --- the heating budget ------------------------------------------------------------------------


def test_at_most_k_printers_of_a_group_heat_at_once() -> None:
    fleet = [printer(f"a{i}", group="A") for i in range(6)]
    fleet += [printer(f"b{i}", group="B") for i in range(2)]
    fleet += [printer("hot", group="A", print_state="printing", heating=True)]
    result = run([job(1, quantity=20)], fleet, heating_budget=3)
    assert Counter(p[0] for _, p in pairs(result)) == {"a": 2, "b": 2}


def test_starts_in_progress_count_against_the_budget() -> None:
    fleet = [printer(f"a{i}", group="A") for i in range(4)]
    fleet += [printer("s1", group="A", attempt_id=1), printer("s2", group="A", attempt_id=2)]
    result = run([job(1, quantity=9)], fleet, heating_budget=3, starting={"s1", "s2"})
    assert len(result.assignments) == 1


def test_a_printer_already_heating_may_start_in_a_full_group() -> None:
    # Preheated by hand: starting it adds no heater to the circuit.
    fleet = [
        printer("warm", group="A", heating=True),
        printer("cold", group="A"),
        printer("busy", group="A", heating=True, print_state="printing"),
    ]
    assert pairs(run([job(1, quantity=2)], fleet, heating_budget=2)) == [(1, "warm")]


def test_printers_without_a_group_share_one_and_no_budget_means_no_limit() -> None:
    fleet = [printer(f"p{i}", group="") for i in range(5)]
    assert len(run([job(1, quantity=5)], fleet, heating_budget=2).assignments) == 2
    assert len(run([job(1, quantity=5)], fleet, heating_budget=None).assignments) == 5


# --- the memo ----------------------------------------------------------------------------------


def test_a_memo_kept_between_rounds_gives_the_same_plans() -> None:
    memo = Memo()
    fleet = [printer("p1"), printer("p2", material="PETG"), printer("p3", nozzle_diameter=0.6)]
    jobs = [job(1, quantity=3, allow=True), job(2, meta={**META, "filament_type": "PETG"})]
    first = run(jobs, fleet, memo=memo)
    assert run(jobs, fleet, memo=memo) == first == run(jobs, fleet)


def test_the_memo_judges_again_when_the_metadata_changed() -> None:
    memo = Memo()
    tall = job(1, sha="f" * 64, meta={**META, "object_height": 500.0})
    assert run([tall], [printer("p1")], memo=memo).assignments == []
    short = job(1, sha="f" * 64, meta=META)
    assert pairs(run([short], [printer("p1")], memo=memo)) == [(1, "p1")]


# --- a whole round, at random ------------------------------------------------------------------

MATERIALS = ("PLA", "PLA", "PLA", "PETG", None)


@st.composite
def fleets(draw: st.DrawFn) -> list[PrinterSnapshot]:
    count = draw(st.integers(0, 16))
    fleet = []
    for i in range(count):
        fleet.append(
            printer(
                f"p{i:02d}",
                connection=draw(st.sampled_from(["online"] * 9 + ["offline"])),
                print_state=draw(st.sampled_from(["standby"] * 6 + ["complete", "printing"])),
                gate_state=draw(st.sampled_from(["available"] * 8 + ["awaiting_clear", "held"])),
                material=draw(st.sampled_from(MATERIALS)),
                nozzle_diameter=draw(st.sampled_from([0.4, 0.4, 0.4, 0.6, None])),
                build_volume=draw(st.sampled_from([(250.0, 250.0, 230.0), (180.0, 180.0, 40.0)])),
                tags=tuple(draw(st.sets(st.sampled_from(["x", "y"])))),
                group=draw(st.sampled_from(["A", "B", ""])),
                heating=draw(st.sampled_from([False, False, True])),
                usage=float(draw(st.integers(0, 3))),
                last_used=draw(st.sampled_from([None, NOW - timedelta(hours=1), NOW])),
            )
        )
    return fleet


@st.composite
def queues(draw: st.DrawFn) -> list[Job]:
    jobs = []
    for jid in range(1, draw(st.integers(0, 8)) + 1):
        quantity = draw(st.integers(1, 4))
        done = draw(st.integers(0, quantity))
        in_flight = draw(st.integers(0, quantity - done))
        jobs.append(
            job(
                jid,
                quantity=quantity,
                done=done,
                in_flight=in_flight,
                priority=draw(st.integers(-1, 1)),
                position=float(draw(st.integers(0, 3))),
                req=Requirements(
                    material=draw(st.sampled_from(("PLA", "PETG", None, None))),
                    nozzle=draw(st.sampled_from([0.4, None, None])),
                    tags=tuple(draw(st.sets(st.sampled_from(["x", "y"]), max_size=1))),
                    printer=draw(st.sampled_from([None] * 6 + ["p01", "p99"])),
                ),
                meta={**META, "object_height": draw(st.sampled_from([20.0, 20.0, 100.0]))},
                allow=draw(st.booleans()),
                failures=draw(st.integers(0, 1)),
                state=draw(st.sampled_from(["queued"] * 6 + ["blocked"])),
                not_before=draw(st.sampled_from([None] * 4 + [NOW + timedelta(hours=1)])),
            )
        )
    return jobs


def _eligible(j: Job, p: PrinterSnapshot) -> bool:
    meta = j.file.meta or None  # empty: the parser found nothing
    verdict = validate("start", p.facts, params={"filename": j.file.name}, file_meta=meta)
    return (
        p.free
        and j.requirements.printer in (None, p.id)
        and problem(j.requirements, p.facts, normal_tags(p.tags)) is None
        and not verdict.blocked
        and (j.allow_mismatch or not verdict.warnings)
    )


def _greedy(
    jobs: list[Job],
    fleet: list[PrinterSnapshot],
    budget: int | None,
    starting: set[str],
    attempts: dict[int, dict[str, int]],
) -> list[tuple[int, str]]:
    """The rules of a round written the slow, obvious way."""
    drawing = {p.id for p in fleet if p.heating or p.id in starting}
    power = Counter(p.power_group for p in fleet if p.id in drawing)
    order = sorted(
        (j for j in jobs if j.state == "queued" and (j.not_before is None or j.not_before <= NOW)),
        key=lambda j: (-j.priority, j.position, j.id),
    )
    taken: list[tuple[int, str]] = []
    for j in order:

        def rank(p: PrinterSnapshot, j: Job = j) -> tuple[Any, ...]:
            used = p.last_used
            wear = (p.usage_seconds, used is not None, used.timestamp() if used else 0.0, p.id)
            return (attempts[j.id].get(p.id, 0), *wear) if j.failures else wear

        for _ in range(j.left):
            options = [
                p for p in fleet
                if p.id not in {t for _, t in taken} and _eligible(j, p)
                and (budget is None or p.id in drawing or power[p.power_group] < budget)
            ]  # fmt: skip
            if not options:
                break
            best = min(options, key=rank)
            taken.append((j.id, best.id))
            if best.id not in drawing:
                drawing.add(best.id)
                power[best.power_group] += 1
    return taken


@given(
    fleet=fleets(),
    jobs=queues(),
    budget=st.sampled_from([None, 0, 1, 2, 3]),
    starting=st.sets(st.sampled_from([f"p{i:02d}" for i in range(16)]), max_size=3),
    seed=st.integers(0, 1000),
)
@settings(max_examples=300)
def test_a_round_keeps_every_rule(
    fleet: list[PrinterSnapshot],
    jobs: list[Job],
    budget: int | None,
    starting: set[str],
    seed: int,
) -> None:
    attempts = {j.id: {"p00": 2, "p01": 1} for j in jobs}
    kw: dict[str, Any] = {"heating_budget": budget, "starting": starting,
                          "attempts_per_printer": attempts}  # fmt: skip
    result = run(jobs, fleet, **kw)
    by_id = {p.id: p for p in fleet}
    by_job = {j.id: j for j in jobs}
    taken = [a.printer for a in result.assignments]
    assert len(taken) == len(set(taken)), "a printer assigned twice"
    for jid, n in Counter(a.job_id for a in result.assignments).items():
        assert n <= by_job[jid].left, "more copies than left"
    for a in result.assignments:
        j = by_job[a.job_id]
        assert j.state == "queued"
        assert j.not_before is None or j.not_before <= NOW
        assert _eligible(j, by_id[a.printer]), "an ineligible printer"
    # Heating: no group above K unless it already was before the round.
    drawing = {p.id for p in fleet if p.heating or p.id in starting}
    before = Counter(by_id[i].power_group for i in drawing)
    after = Counter(by_id[i].power_group for i in drawing | set(taken))
    for group, n in after.items():
        if budget is not None and n > before[group]:
            assert n <= budget, f"group {group!r}: {n} heating, budget {budget}"
    # Nothing left unused: a job that still waits found no eligible printer free.
    got = Counter(a.job_id for a in result.assignments)
    for j in jobs:
        if j.state != "queued" or got[j.id] >= j.left or (j.not_before and j.not_before > NOW):
            continue
        for p in fleet:
            if p.id in taken or not _eligible(j, p):
                continue
            full = budget is not None and after[p.power_group] >= budget
            assert full, f"job {j.id} left {p.id} unused"
            assert p.id not in drawing, f"job {j.id} left {p.id} unused (it draws no more)"
    # Exactly what a plain greedy pass over every printer picks (the planner's kinds, heaps
    # and memo are only there to be fast).
    assert pairs(result) == _greedy(jobs, fleet, budget, starting, attempts)
    # Deterministic, whatever the order of the inputs.
    rng = random.Random(seed)
    shuffled_fleet, shuffled_jobs = fleet[:], jobs[:]
    rng.shuffle(shuffled_fleet)
    rng.shuffle(shuffled_jobs)
    assert run(shuffled_jobs, shuffled_fleet, **kw) == result


# --- purity ------------------------------------------------------------------------------------

PURE_MODULES = ("rules", "planner", "eligibility", "why", "reasons", "heating")
PURE_IMPORTS = (
    "__future__", "collections", "collections.abc", "dataclasses", "datetime", "typing", "re",
    "heapq", "itertools",
    "kybercore.core.validation", "kybercore.core.messages", "kybercore.core.numbers",
    "kybercore.jobs.models", "kybercore.registry.models",
    *(f"kybercore.jobs.{name}" for name in PURE_MODULES),
)  # fmt: skip


@pytest.mark.parametrize("module", PURE_MODULES)
def test_the_rules_import_nothing_that_does_io(module: str) -> None:
    import kybercore.jobs

    path = Path(kybercore.jobs.__file__).parent / f"{module}.py"
    imported = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            imported |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, "relative import"
            imported.add(node.module or "")
    assert imported - set(PURE_IMPORTS) == set()
