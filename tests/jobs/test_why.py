"""Why a job waits, and what can never print: every line code, on a real situation each.

The cases together must produce every code of the catalogue (a code nobody can produce is
dead; one produced but not catalogued would raise).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import replace
from datetime import timedelta
from typing import Any

import pytest

from kybercore.jobs.models import JobFile, NewJob, Requirements
from kybercore.jobs.reasons import MESSAGES, WhyLine
from kybercore.jobs.rules import PrinterSnapshot, never_printable, why
from tests.jobs.test_rules import META, NOW, gate, job, printer

Case = Callable[[], list[WhyLine]]


def explain(j: Any, printers: list[PrinterSnapshot], queue: list[Any] | None = None,
            **kw: Any) -> list[WhyLine]:  # fmt: skip
    options: dict[str, Any] = {"heating_budget": None, "now": NOW, **kw}
    return why(j, printers, queue=queue if queue is not None else [j], **options)


def held_by_hand(reason: str, state: str = "held") -> PrinterSnapshot:
    return replace(printer("p1"), gate=gate("p1", state, reason=reason))


PLA = Requirements(material="PLA")

# code -> (the situation, a line it must contain as "subject: English")
WHY: dict[str, tuple[Case, str]] = {
    "job_blocked": (lambda: explain(job(1, state="blocked", reason="Nozzle clogged."), []),
        "queue: blocked: Nozzle clogged. Requeue it once the cause is fixed."),
    "job_done": (lambda: explain(job(1, state="done"), []), "queue: done: every copy is printed"),
    "job_cancelled": (lambda: explain(job(1, state="cancelled"), []), "queue: cancelled"),
    "no_copies_left": (lambda: explain(job(1, quantity=2, done=1, in_flight=1), [printer("p1")]),
        "queue: every copy left is printing or awaiting a verdict"),
    "queue_paused": (lambda: explain(job(1), [printer("p1")], paused=True),
        "queue: the queue is paused; resume it to dispatch jobs"),
    "eligible": (lambda: explain(job(1), [printer("p1")], paused=True),
        "p1: could print it once the queue sends it"),
    "not_before": (lambda: explain(job(1, not_before=NOW + timedelta(days=1)), [printer("p1")]),
        "queue: waits until 2026-05-02 14:30"),
    "no_printers": (lambda: explain(job(1), []), "queue: no printers are configured; add one"),
    "pinned": (lambda: explain(job(1, req=Requirements(printer="p2")),
                               [printer("p1"), printer("p2")]),
        "queue: pinned to p2: no other printer is considered"),
    "assigned": (lambda: explain(job(1, req=Requirements(printer="p2")),
                                 [printer("p1"), printer("p2")]),
        "p2: gets a copy in the next dispatch round"),
    "pinned_unknown": (lambda: explain(job(1, req=Requirements(printer="p9")), [printer("p1")]),
        "p9: the job is pinned to this printer, which is not configured"),
    "needs_material": (lambda: explain(job(1, req=PLA), [printer("p1", material="PETG")]),
        "p1: PETG loaded, job needs PLA"),
    "material_unknown": (lambda: explain(job(1, req=PLA), [printer("p1", material=None)]),
        "p1: no loaded material recorded, job needs PLA; set it in the printer's settings"),
    "needs_nozzle": (lambda: explain(job(1, req=Requirements(nozzle=0.4)),
                                     [printer("p1", nozzle_diameter=0.6)]),
        "p1: 0.6 mm nozzle, job needs 0.4 mm"),
    "nozzle_unknown": (lambda: explain(job(1, req=Requirements(nozzle=0.4)),
                                       [printer("p1", nozzle_diameter=None)]),
        "p1: nozzle size unknown, job needs 0.4 mm"),
    "needs_model": (lambda: explain(job(1, req=Requirements(model="Prusa MK4")), [printer("p1")]),
        "p1: model 'Voron 2.4', job needs 'Prusa MK4'"),
    "needs_tags": (lambda: explain(job(1, req=Requirements(tags=("fast", "b"))),
                                   [printer("p1", tags=("fast",))]),
        "p1: lacks tag b"),
    "printer_offline": (lambda: explain(job(1), [printer("p1", connection="offline")]),
        "p1: offline"),
    "printer_disabled": (lambda: explain(job(1), [printer("p1", connection="disabled")]),
        "p1: disabled in KyberCore"),
    "printer_connecting": (lambda: explain(job(1), [printer("p1", connection="connecting")]),
        "p1: connecting"),
    "printer_auth_failed": (lambda: explain(job(1), [printer("p1", connection="auth_failed")]),
        "p1: Moonraker refuses its API key"),
    "klippy_not_ready": (lambda: explain(job(1), [printer("p1", klippy_state="shutdown")]),
        "p1: Klipper is shutdown, not ready"),
    "awaiting_clear": (lambda: explain(job(1), [printer("p1", gate_state="awaiting_clear")]),
        "p1: awaiting clear since 14:00"),
    "held": (lambda: explain(job(1), [held_by_hand("bed warped")]), "p1: held: bed warped"),
    "maintenance": (lambda: explain(job(1), [held_by_hand("", "maintenance")]),
        "p1: in maintenance"),
    "printer_busy": (lambda: explain(job(1), [printer("p1", print_state="paused")]),
        "p1: busy: paused"),
    "printer_starting": (lambda: explain(job(1), [printer("p1", attempt_id=7)]),
        "p1: starting attempt 7"),
    "print_state_unknown": (lambda: explain(job(1), [printer("p1", print_state="")]),
        "p1: print state unknown (?)"),
    "waiting_for_power": (lambda: explain(job(1, quantity=9), [
            printer("hot", print_state="printing", heating=True), printer("p1"), printer("p2"),
        ] + [printer(f"q{i}") for i in range(5)], heating_budget=2),
        "power group A: 2 of 2 heating; p2, q0, q1, q2, q3, +1 wait"),
    "taken_by_job": (lambda: explain(job(2), [printer("p1")], [job(1, priority=1), job(2)]),
        "p1: goes to job 1 first (ahead in the queue)"),
    "ranked_lower": (lambda: explain(job(1), [printer("p1"), printer("p2", usage=5.0)]),
        "p2: could print it, but the copies left go to less-used printers"),
    # --- never printable ---
    "no_model": (lambda: never_printable(new(req=Requirements(model="Bambu X1C")),
                                         [printer("p1"), printer("p2", model="Prusa MK4")]),
        "queue: no printer is a 'Bambu X1C' (models: Prusa MK4, Voron 2.4)"),
    "no_tags": (lambda: never_printable(new(req=Requirements(tags=("a", "b"))),
                                        [printer("p1", tags=("a",)), printer("p2", tags=("b",))]),
        "queue: no printer has every tag of a, b"),
    "no_nozzle": (lambda: never_printable(new(nozzle_diameter=0.25),
                                          [printer("p1"), printer("p2", nozzle_diameter=0.6)]),
        "queue: no printer has a 0.25 mm nozzle (nozzles: 0.4, 0.6)"),
    "too_tall": (lambda: never_printable(new(object_height=300.0), [
            printer("p1"), printer("p2", build_volume=(300.0, 300.0, 280.0)),
        ]),
        "queue: the part is 300 mm tall; the tallest Z travel is 280 mm"),
    "too_hot": (lambda: never_printable(new(first_layer_bed_temp=130.0), [printer("p1")]),
        "queue: the first layer heats the bed to 130 °C; the highest maximum is 120 °C"),
    "no_printer_fits": (lambda: never_printable(new(object_height=100.0, nozzle_diameter=0.6), [
            printer("short", nozzle_diameter=0.6, build_volume=(200.0, 200.0, 50.0)),
            printer("tall", nozzle_diameter=0.4),
        ]),
        "queue: no single printer meets all of: a 0.6 mm nozzle; Z travel of 100 mm; "
        "hotend up to 205 °C; bed up to 60 °C"),
}  # fmt: skip


def new(req: Requirements | None = None, **meta: Any) -> NewJob:
    return NewJob(JobFile("a" * 64, "part.gcode", 10, {**META, **meta}), requirements=req or
                  Requirements())  # fmt: skip


@pytest.mark.parametrize("code", sorted(WHY))
def test_each_line_says_why(code: str) -> None:
    case, expected = WHY[code]
    lines = case()
    assert expected in [str(w) for w in lines]
    assert code in {w.code for w in lines}


def test_every_catalogued_line_has_a_case() -> None:
    assert set(WHY) == set(MESSAGES)


def test_every_line_has_both_languages_with_the_same_placeholders() -> None:
    def names(text: str) -> set[str]:  # "heater_en" in English is "heater_es" in Spanish
        return {re.sub(r"_(en|es)$", "", n) for n in re.findall(r"\{(\w+)\}", text)}

    for code, (en, es) in MESSAGES.items():
        assert names(en) == names(es), code
        assert en != es, code  # not left untranslated


def test_spanish_writes_numbers_its_way() -> None:
    (line,) = [w for w in WHY["needs_nozzle"][0]() if w.code == "needs_nozzle"]
    assert line.es == "boquilla de 0,6 mm, el trabajo necesita 0,4 mm"


def test_a_file_check_keeps_validations_code_and_says_what_to_do() -> None:
    tall = explain(job(1, meta={**META, "object_height": 240.0}), [printer("p1")])
    assert [(w.subject, w.code) for w in tall] == [("p1", "file_too_tall")]
    assert "240 mm tall" in tall[0].en
    petg = explain(job(1, meta={**META, "filament_type": "PETG"}), [printer("p1")])
    assert [w.code for w in petg] == ["filament_mismatch"]
    assert petg[0].en.endswith("queue it with allow mismatch to dispatch it anyway.")
    assert "permitiéndolas" in petg[0].es


def test_a_short_spool_says_how_much_the_job_needs_and_how_much_is_left() -> None:
    meta = {**META, "filament_weight_total": 40.0}
    lines = explain(job(1, meta=meta), [printer("p1", filament_left_g=25.0)])
    assert [(w.subject, w.code) for w in lines] == [("p1", "not_enough_filament")]
    assert "needs 40 g of filament but the loaded spool has 25 g left" in lines[0].en
    assert "40 g de filamento" in lines[0].es


def test_a_wrong_material_outranks_the_printers_state() -> None:
    # It would never get the job even when idle: say that, not "busy".
    lines = explain(job(1, req=PLA), [printer("p1", material="PETG", print_state="printing")])
    assert [w.code for w in lines] == ["needs_material"]
    # A fact missing because the printer is offline: the state says more.
    lines = explain(job(1, req=PLA), [printer("p1", material=None, connection="offline")])
    assert [w.code for w in lines] == ["printer_offline"]


def test_the_three_printers_of_the_issue() -> None:
    fleet = [printer("pla-1"), printer("pla-2", gate_state="awaiting_clear", attempt_id=3),
             printer("petg", material="PETG")]  # fmt: skip
    lines = explain(job(1, quantity=5, in_flight=1, req=PLA), fleet)
    assert [str(w) for w in lines] == [
        "pla-1: gets a copy in the next dispatch round",
        "pla-2: awaiting clear since 14:00",
        "petg: PETG loaded, job needs PLA",
    ]


def test_an_ordinary_job_is_never_rejected_at_submission() -> None:
    fleet = [printer("p1", material="PETG"), printer("p2", material=None, build_volume=None)]
    # Wrong material everywhere can be loaded; a Z travel nobody read yet is not guessed.
    assert never_printable(new(req=PLA, object_height=900.0), fleet) == []
    assert never_printable(new(), []) == []
    assert never_printable(new(req=Requirements(printer="p1", model="voron2.4")), fleet) == []
    assert [w.code for w in never_printable(new(req=Requirements(printer="zz")), fleet)] == [
        "pinned_unknown"
    ]
