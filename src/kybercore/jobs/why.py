"""Why a job is waiting, printer by printer; and whether it could ever print at all. Pure.

:func:`why` answers ``GET /api/jobs/{id}/why``: one line per printer saying why the job is
not running there right now (``printer-7: awaiting clear since 14:02``, ``printer-9: PETG
loaded, job needs PLA``), one per power group that holds printers back (``power group A:
3 of 3 heating``) and lines about the job as a whole (``queue: the queue is paused``). It
runs the same round :func:`kybercore.jobs.planner.plan` would, so it can tell "goes to a
job ahead in the queue" from "could print it".

:func:`never_printable` rejects a job at submission when no configured printer could ever
run it, whatever is loaded or printing: taller than every Z travel, a nozzle nobody has, a
first layer hotter than any heater may go, a model or tags nobody has, pinned to a printer
that is not there. The loaded material is not such a reason: an operator can change it.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from datetime import datetime
from typing import Any, Final

from kybercore.core.numbers import finite_number
from kybercore.jobs.eligibility import (
    IDLE_STATES,
    NOZZLE_TOLERANCE,
    UNKNOWN_FACTS,
    Memo,
    PrinterSnapshot,
    clock,
    normal_model,
    normal_tags,
    unmet,
)
from kybercore.jobs.models import Job, NewJob
from kybercore.jobs.planner import plan
from kybercore.jobs.reasons import QUEUE, WhyLine, finding, line, number

_CONNECTION: Final = {
    "disabled": "printer_disabled",
    "connecting": "printer_connecting",
    "auth_failed": "printer_auth_failed",
}
_BUSY: Final = {"printing": "imprimiendo", "paused": "en pausa"}
_LISTED: Final = 5
"""Printer ids named in a power group's line before "+N"."""


def why(
    job: Job,
    printers: Sequence[PrinterSnapshot],
    *,
    queue: Sequence[Job],
    heating_budget: int | None,
    starting: Collection[str] = (),
    now: datetime,
    paused: bool = False,
    attempts_per_printer: Mapping[int, Mapping[str, int]] | None = None,
    memo: Memo | None = None,
) -> list[WhyLine]:
    """Why ``job`` is not running on each printer now; ``queue`` is every job the round
    would see, and the other arguments are :func:`~kybercore.jobs.planner.plan`'s."""
    if job.state != "queued":
        if job.state == "blocked":
            return [line(QUEUE, "job_blocked", reason=job.reason)]
        return [line(QUEUE, f"job_{job.state}")]
    if job.left <= 0:
        return [line(QUEUE, "no_copies_left")]
    lines: list[WhyLine] = []
    if paused:
        lines.append(line(QUEUE, "queue_paused"))
    if job.not_before is not None and job.not_before > now:
        lines.append(line(QUEUE, "not_before", time=clock(job.not_before, now)))
    held = bool(lines)
    if not printers:
        return [*lines, line(QUEUE, "no_printers")]
    explained = printers
    pinned = job.requirements.printer
    if pinned:
        lines.append(line(QUEUE, "pinned", printer=pinned))
        explained = [p for p in printers if p.id == pinned]
        if not explained:
            return [*lines, line(pinned, "pinned_unknown")]
    memo = memo or Memo()
    others = [j for j in queue if j.id != job.id]
    # The round as it would run now (resumed, if paused), this job in its place.
    round_plan = plan(
        [*others, job], printers, heating_budget=heating_budget, starting=starting, now=now,
        attempts_per_printer=attempts_per_printer, memo=memo,
    )  # fmt: skip
    taken = {a.printer: a.job_id for a in round_plan.assignments}
    power = _power(printers, starting, taken)
    waiting_for_power: dict[str, list[str]] = {}
    for p in explained:
        found = _printer_line(job, p, now, memo)
        if found is not None:
            lines.append(found)
        elif held:
            lines.append(line(p.id, "eligible"))
        elif taken.get(p.id) == job.id:
            lines.append(line(p.id, "assigned"))
        elif p.id in taken:
            lines.append(line(p.id, "taken_by_job", job=str(taken[p.id])))
        elif (
            heating_budget is not None
            and not (p.heating or p.id in starting)
            and power.get(p.power_group, 0) >= heating_budget
        ):
            waiting_for_power.setdefault(p.power_group, []).append(p.id)
        else:
            lines.append(line(p.id, "ranked_lower"))
    for group, ids in waiting_for_power.items():
        shown = ", ".join(ids[:_LISTED]) + (
            f", +{len(ids) - _LISTED}" if len(ids) > _LISTED else ""
        )
        lines.append(
            line(
                f"power group {group or '(none)'}", "waiting_for_power",
                heating=str(power[group]), budget=str(heating_budget), printers=shown,
            )
        )  # fmt: skip
    return lines


def _printer_line(job: Job, p: PrinterSnapshot, now: datetime, memo: Memo) -> WhyLine | None:
    """Why ``p`` cannot take ``job`` whatever the rest of the queue does, or None."""
    req_line = unmet(p.id, job.requirements, p.facts, normal_tags(p.tags))
    if req_line is not None and req_line.code not in UNKNOWN_FACTS:
        return req_line
    state_line = _state_line(p, now)
    if state_line is not None:
        return state_line
    if req_line is not None:
        return req_line
    verdict = memo.verdict(job.file, p.facts)
    blocking = [r for r in verdict.reasons if r.level == "block"]
    if blocking:
        return finding(p.id, blocking[0])
    if verdict.warnings and not job.allow_mismatch:
        return finding(p.id, verdict.warnings[0], mismatch=True)
    return None


def _state_line(p: PrinterSnapshot, now: datetime) -> WhyLine | None:
    """Why ``p`` can take no job now: its gate, connection, Klippy or print."""
    gate, facts = p.gate, p.facts
    if gate.state == "awaiting_clear":
        return line(p.id, "awaiting_clear", since=clock(gate.since, now))
    if gate.state in ("held", "maintenance"):
        return line(p.id, gate.state, detail=f": {gate.reason}" if gate.reason else "")
    if facts.connection != "online":
        return line(p.id, _CONNECTION.get(facts.connection, "printer_offline"))
    if facts.klippy_state != "ready":
        return line(p.id, "klippy_not_ready", state=facts.klippy_state or "?")
    if facts.print_state in _BUSY:
        state = facts.print_state
        return line(p.id, "printer_busy", state_en=state, state_es=_BUSY[state])
    if gate.attempt_id is not None:
        return line(p.id, "printer_starting", attempt=str(gate.attempt_id))
    if facts.print_state not in IDLE_STATES:
        return line(p.id, "print_state_unknown", state=facts.print_state or "?")
    return None


def _power(
    printers: Sequence[PrinterSnapshot], starting: Collection[str], taken: Mapping[str, int]
) -> dict[str, int]:
    """Printers heating or starting per power group once the round's starts are made."""
    power: dict[str, int] = {}
    for p in printers:
        if p.heating or p.id in starting or p.id in taken:
            power[p.power_group] = power.get(p.power_group, 0) + 1
    return power


# --- never printable -----------------------------------------------------------------------

Check = tuple[Callable[[PrinterSnapshot], bool], Callable[[Sequence[PrinterSnapshot]], WhyLine]]


def never_printable(new: NewJob, printers: Sequence[PrinterSnapshot]) -> list[WhyLine]:
    """Why no printer could ever run ``new``, or ``[]`` when one could (or none is
    configured yet: the job then waits, and :func:`why` says so).

    ``printers``: every configured printer, disabled and offline ones included. A fact
    nobody knows (a Z travel not read yet) never rejects a job."""
    if not printers:
        return []
    req, meta = new.requirements, new.file.meta
    if req.printer:
        printers = [p for p in printers if p.id == req.printer]
        if not printers:
            return [line(req.printer, "pinned_unknown")]
    checks = _checks(new, meta)
    if any(all(could(p) for could, _ in checks) for p in printers):
        return []
    lines = [explain(printers) for could, explain in checks if not any(map(could, printers))]
    if lines:
        return lines
    needs_en, needs_es = zip(*(_need(new, meta)), strict=True)
    return [
        line(QUEUE, "no_printer_fits", needs_en="; ".join(needs_en), needs_es="; ".join(needs_es))
    ]


def _checks(new: NewJob, meta: Mapping[str, Any]) -> list[Check]:
    """What each printer must have, with the line that says nobody has it."""
    req = new.requirements
    checks: list[Check] = []
    if req.model:
        model = normal_model(req.model)
        checks.append((
            lambda p: normal_model(p.facts.model) == model,
            lambda ps: line(QUEUE, "no_model", model=req.model or "",
                            models=_listing(p.facts.model for p in ps)),
        ))  # fmt: skip
    if req.tags:
        tags = normal_tags(req.tags)
        checks.append((
            lambda p: tags <= normal_tags(p.tags),
            lambda ps: line(QUEUE, "no_tags", tags=", ".join(req.tags)),
        ))  # fmt: skip
    for nozzle in (req.nozzle, finite_number(meta.get("nozzle_diameter"))):
        if nozzle is not None:
            checks.append(_nozzle_check(nozzle))
    height = finite_number(meta.get("object_height"))
    if height is not None:
        checks.append((
            lambda p: p.facts.build_volume is None or p.facts.build_volume[2] >= height - 1e-6,
            lambda ps: line(QUEUE, "too_tall", height=height,
                            z=max(p.facts.build_volume[2] for p in ps if p.facts.build_volume)),
        ))  # fmt: skip
    for key, attr, heater in (
        ("first_layer_extr_temp", "max_extruder_temp", ("hotend", "la boquilla")),
        ("first_layer_bed_temp", "max_bed_temp", ("bed", "la cama")),
    ):
        temp = finite_number(meta.get(key))
        if temp is not None:
            checks.append(_temp_check(temp, attr, heater))
    return checks


def _nozzle_check(nozzle: float) -> Check:
    def could(p: PrinterSnapshot) -> bool:
        ours = p.facts.nozzle_diameter
        return ours is None or abs(ours - nozzle) <= NOZZLE_TOLERANCE

    def explain(ps: Sequence[PrinterSnapshot]) -> WhyLine:
        sizes = sorted({p.facts.nozzle_diameter for p in ps if p.facts.nozzle_diameter})
        return line(QUEUE, "no_nozzle", nozzle=nozzle, nozzles=_listing(map(number, sizes)))

    return could, explain


def _temp_check(temp: float, attr: str, heater: tuple[str, str]) -> Check:
    def limit(p: PrinterSnapshot) -> float | None:
        value: float | None = getattr(p.facts, attr)
        return value

    def could(p: PrinterSnapshot) -> bool:
        most = limit(p)
        return most is None or temp <= most

    def explain(ps: Sequence[PrinterSnapshot]) -> WhyLine:
        highest = max(m for p in ps if (m := limit(p)) is not None)
        return line(QUEUE, "too_hot", heater_en=heater[0], heater_es=heater[1], temp=temp,
                    limit=highest)  # fmt: skip

    return could, explain


def _need(new: NewJob, meta: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Everything the job asks of one printer, in English and Spanish."""
    req, needs = new.requirements, []
    if req.model:
        needs.append((f"model '{req.model}'", f"modelo «{req.model}»"))
    if req.tags:
        needs.append((f"tags {', '.join(req.tags)}", f"etiquetas {', '.join(req.tags)}"))
    for nozzle in (req.nozzle, finite_number(meta.get("nozzle_diameter"))):
        if nozzle is not None:
            needs.append((f"a {number(nozzle)} mm nozzle",
                          f"boquilla de {number(nozzle, 'es')} mm"))  # fmt: skip
    height = finite_number(meta.get("object_height"))
    if height is not None:
        needs.append((f"Z travel of {number(height)} mm",
                      f"recorrido en Z de {number(height, 'es')} mm"))  # fmt: skip
    for key, en, es in (
        ("first_layer_extr_temp", "hotend", "boquilla"), ("first_layer_bed_temp", "bed", "cama"),
    ):  # fmt: skip
        temp = finite_number(meta.get(key))
        if temp is not None:
            needs.append((f"{en} up to {number(temp)} °C", f"{es} hasta {number(temp, 'es')} °C"))
    return needs


def _listing(values: Any) -> str:
    """Distinct non-empty values, sorted, at most eight."""
    found = sorted({str(v).strip() for v in values} - {""})
    return ", ".join(found[:8]) + (", …" if len(found) > 8 else "") if found else "—"
