"""The noise filter: cooldown, alerts paired with recoveries, storms and plates folded.

Pure and deterministic: time is the ``now`` passed in. The flapping printer runs the real
detector and filter together, second by second, for twenty minutes of simulated time.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from itertools import pairwise
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from kybercore.notify.detector import Detector, Observation
from kybercore.notify.models import EventKind, FleetEvent, NoiseSettings, PrinterRef
from kybercore.notify.noise import NoiseFilter

T0 = datetime(2026, 5, 1, 22, 0, tzinfo=UTC)


def printer(n: int, location: str | None = "Room B") -> PrinterRef:
    return PrinterRef(f"printer-{n}", f"Printer {n}", location, ())


P1 = printer(1)


def ev(kind: EventKind, who: PrinterRef | None = P1, **params: Any) -> FleetEvent:
    return FleetEvent(kind, T0, who, params)


def noise(**settings: Any) -> NoiseFilter:
    return NoiseFilter(NoiseSettings(**settings))


def kinds(events: list[FleetEvent]) -> list[str]:
    return [event.kind for event in events]


def test_the_same_event_of_the_same_printer_is_told_once_per_cooldown() -> None:
    f = noise(cooldown_s=300.0)
    assert kinds(f.push(ev("print_failed"), 0.0)) == ["print_failed"]
    assert f.push(ev("print_failed"), 299.0) == []
    assert kinds(f.push(ev("print_failed"), 300.0)) == ["print_failed"]


def test_the_cooldown_is_per_printer_and_kind() -> None:
    f = noise()
    assert kinds(f.push(ev("print_failed"), 0.0)) == ["print_failed"]
    assert kinds(f.push(ev("print_failed", printer(2)), 1.0)) == ["print_failed"]
    assert kinds(f.push(ev("print_started"), 2.0)) == ["print_started"]


def test_blocked_jobs_are_cooled_down_per_job() -> None:
    f = noise()
    assert len(f.push(ev("job_blocked", None, job_id=1), 0.0)) == 1
    assert len(f.push(ev("job_blocked", None, job_id=2), 1.0)) == 1
    assert f.push(ev("job_blocked", None, job_id=1), 2.0) == []


def test_test_events_are_never_filtered() -> None:
    f = noise()
    assert [len(f.push(ev("test", None), float(t))) for t in range(3)] == [1, 1, 1]


def test_an_offline_alert_is_held_for_the_fold_window_then_its_recovery_passes() -> None:
    f = noise(fold_window_s=20.0)
    assert f.push(ev("printer_offline", was="printing"), 0.0) == []
    assert f.release(19.9) == []
    assert kinds(f.release(20.0)) == ["printer_offline"]
    assert f.release(100.0) == []
    assert kinds(f.push(ev("printer_recovered", what="connection"), 60.0)) == ["printer_recovered"]
    assert f.push(ev("printer_recovered", what="connection"), 61.0) == []


def test_a_recovery_without_an_alert_told_is_dropped() -> None:
    f = noise()
    assert f.push(ev("printer_recovered", what="connection"), 0.0) == []
    assert kinds(f.push(ev("klippy_shutdown"), 1.0)) == ["klippy_shutdown"]
    # The Klippy alert does not make a connection recovery news.
    assert f.push(ev("printer_recovered", what="connection"), 2.0) == []
    assert kinds(f.push(ev("printer_recovered", what="klippy"), 3.0)) == ["printer_recovered"]


def test_a_recovery_inside_the_fold_window_follows_its_alert() -> None:
    f = noise(fold_window_s=20.0)
    f.push(ev("printer_offline", was="printing"), 0.0)
    assert f.push(ev("printer_recovered", what="connection"), 5.0) == []
    assert kinds(f.release(20.0)) == ["printer_offline", "printer_recovered"]


def test_with_no_fold_window_an_alert_goes_out_at_once() -> None:
    f = noise(fold_window_s=0.0)
    assert kinds(f.push(ev("printer_offline"), 0.0)) == ["printer_offline"]


def test_a_flapping_printer_sends_one_alert_and_one_recovery_per_cooldown() -> None:
    cooldown = 300.0
    settings = NoiseSettings(cooldown_s=cooldown, fold_window_s=20.0)
    detector, f = Detector(settings), NoiseFilter(settings)
    printing = Observation("online", "ready", "", "printing", "tower.gcode", "", None, False)
    offline = Observation("offline", "disconnected", "", "printing", "tower.gcode", "", None, False)
    out: list[tuple[float, str]] = []
    detector.observe(P1, printing, -1.0, T0)
    for second in range(20 * 60):
        now, at = float(second), T0 + timedelta(seconds=second)
        if second % 10 == 0:  # offline, online, offline ... every 10 s
            observation = offline if second % 20 == 0 else printing
            for event in detector.observe(P1, observation, now, at):
                out += [(now, e.kind) for e in f.push(event, now)]
        out += [(now, e.kind) for e in f.release(now)]
    alerts = [t for t, kind in out if kind == "printer_offline"]
    recoveries = [t for t, kind in out if kind == "printer_recovered"]
    # 20 minutes are four cooldown windows: one alert and one recovery in each.
    assert len(alerts) == len(recoveries) == 4
    assert [int(t // cooldown) for t in alerts] == [0, 1, 2, 3]
    assert [int(t // cooldown) for t in recoveries] == [0, 1, 2, 3]
    assert all(b - a >= cooldown for a, b in pairwise(alerts))
    assert [kind for _, kind in out] == ["printer_offline", "printer_recovered"] * 4


def test_twelve_printers_of_one_room_going_offline_make_one_storm() -> None:
    f = noise(fold_window_s=20.0, storm_threshold=3)
    room = [printer(n) for n in range(1, 13)]
    for n, p in enumerate(room):
        assert f.push(ev("printer_offline", p, was="printing"), n / 12) == []
    assert f.release(19.9) == []
    [storm] = f.release(20.0)
    assert (storm.kind, storm.printer) == ("storm_offline", None)
    assert storm.params == {
        "location": "Room B",
        "count": 12,
        "printers": [p.id for p in room],
        "names": [p.name for p in room],
    }
    assert storm.severity == "critical"
    # Power back: the storm's recoveries fold the same way.
    for n, p in enumerate(room):
        assert f.push(ev("printer_recovered", p, what="connection"), 60.0 + n / 12) == []
    [back] = f.release(80.0)
    assert (back.kind, back.printer) == ("printer_recovered", None)
    assert back.params["count"] == 12
    assert back.params["location"] == "Room B"


def test_two_printers_offline_are_two_events() -> None:
    f = noise(storm_threshold=3)
    f.push(ev("printer_offline", printer(1)), 0.0)
    f.push(ev("printer_offline", printer(2)), 0.5)
    out = f.release(20.0)
    assert kinds(out) == ["printer_offline", "printer_offline"]
    assert [e.printer.id for e in out if e.printer] == ["printer-1", "printer-2"]


def test_a_lone_recovery_of_a_storm_printer_is_its_own_event() -> None:
    f = noise(storm_threshold=1)
    f.push(ev("printer_offline", printer(1)), 0.0)
    f.push(ev("printer_offline", printer(2)), 0.0)
    assert kinds(f.release(20.0)) == ["storm_offline"]
    f.push(ev("printer_recovered", printer(1), what="connection"), 30.0)
    [back] = f.release(50.0)
    assert back.printer == printer(1)


def test_each_location_folds_on_its_own() -> None:
    f = noise(storm_threshold=3)
    for n in range(4):
        f.push(ev("printer_offline", printer(n, "Room A")), 0.0)
        f.push(ev("printer_offline", printer(10 + n, "Room B")), 0.0)
    for n in range(2):
        f.push(ev("printer_offline", printer(20 + n, "Room C")), 0.0)
    for n in range(4):
        f.push(ev("printer_offline", printer(30 + n, None)), 0.0)
    out = f.release(20.0)
    storms = {e.params["location"]: e.params["count"] for e in out if e.kind == "storm_offline"}
    assert storms == {"Room A": 4, "Room B": 4, None: 4}
    singles = [e.printer.id for e in out if e.kind == "printer_offline" and e.printer]
    assert singles == ["printer-20", "printer-21"]


def test_the_fold_window_opens_with_the_first_of_its_group() -> None:
    f = noise(fold_window_s=20.0, storm_threshold=3)
    for n in range(3):
        f.push(ev("printer_offline", printer(n)), 0.0)
    assert kinds(f.release(20.0)) == ["printer_offline"] * 3
    f.push(ev("printer_offline", printer(9)), 21.0)
    f.push(ev("printer_offline", printer(8)), 40.0)
    assert f.release(40.9) == []
    assert kinds(f.release(41.0)) == ["printer_offline"] * 2


def test_a_push_lets_out_what_is_due_by_then() -> None:
    f = noise(fold_window_s=20.0)
    f.push(ev("printer_offline", printer(1)), 0.0)
    assert kinds(f.push(ev("print_started", printer(2)), 30.0)) == [
        "printer_offline",
        "print_started",
    ]


def test_several_plates_waiting_fold_into_one() -> None:
    f = noise()
    for n in range(3):
        f.push(ev("plate_waiting", printer(n, f"Room {n}"), minutes=31), float(n))
    [plates] = f.release(20.0)
    assert (plates.kind, plates.printer) == ("plate_waiting", None)
    assert plates.params == {
        "count": 3,
        "printers": ["printer-0", "printer-1", "printer-2"],
        "names": ["Printer 0", "Printer 1", "Printer 2"],
    }
    f.push(ev("plate_waiting", printer(7), minutes=31), 30.0)
    [alone] = f.release(50.0)
    assert alone.printer == printer(7)


def test_plates_of_one_location_say_where() -> None:
    f = noise()
    f.push(ev("plate_waiting", printer(1)), 0.0)
    f.push(ev("plate_waiting", printer(2)), 0.0)
    [plates] = f.release(20.0)
    assert plates.params["location"] == "Room B"
    f.push(ev("plate_waiting", printer(3, None)), 30.0)
    f.push(ev("plate_waiting", printer(4, None)), 30.0)
    [nowhere] = f.release(50.0)
    assert "location" not in nowhere.params


def test_new_settings_apply_to_the_next_event() -> None:
    f = noise(cooldown_s=300.0)
    f.push(ev("print_failed"), 0.0)
    f.update(NoiseSettings(cooldown_s=10.0))
    assert kinds(f.push(ev("print_failed"), 10.0)) == ["print_failed"]


def test_printers_no_worker_reports_fold_fleet_wide_and_so_do_their_returns() -> None:
    # A worker dies: its printers, in any room, are one message; so is their return.
    f = noise(fold_window_s=20.0, storm_threshold=3)
    lost = [printer(1, "Room A"), printer(2, "Room B"), printer(3, None)]
    for n, p in enumerate(lost):
        assert f.push(ev("printer_unreported", p, seconds=30), n / 2) == []
    [told] = f.release(20.0)
    assert (told.kind, told.printer, told.severity) == ("printer_unreported", None, "critical")
    assert told.params == {
        "count": 3,
        "printers": [p.id for p in lost],
        "names": [p.name for p in lost],
    }
    for n, p in enumerate(lost):
        assert f.push(ev("printer_recovered", p, what="worker"), 60.0 + n) == []
    [back] = f.release(80.0)
    assert (back.kind, back.printer) == ("printer_recovered", None)
    assert back.params == {**told.params, "what": "worker"}


def test_one_printer_no_worker_reports_is_its_own_event_and_so_is_its_return() -> None:
    f = noise(fold_window_s=20.0)
    f.push(ev("printer_unreported", seconds=30), 0.0)
    # Reported again inside the window: the return waits for its alert, then follows it.
    assert f.push(ev("printer_recovered", what="worker"), 5.0) == []
    alert, back = f.release(20.0)
    assert (alert.kind, alert.printer) == ("printer_unreported", P1)
    assert (back.kind, back.params) == ("printer_recovered", {"what": "worker"})


def test_a_worker_return_does_not_close_an_offline_alert() -> None:
    f = noise(fold_window_s=0.0)
    assert kinds(f.push(ev("printer_offline"), 0.0)) == ["printer_offline"]
    assert f.push(ev("printer_recovered", what="worker"), 1.0) == []
    assert kinds(f.push(ev("printer_recovered", what="connection"), 2.0)) == ["printer_recovered"]


# --- property: never two of a kind per printer within cooldown; recoveries end alerts --------

_P = [printer(1, "A"), printer(2, "A"), printer(3, "B"), printer(4, None)]
_KINDS: list[EventKind] = [
    "printer_offline", "printer_recovered", "klippy_shutdown", "klippy_error",
    "plate_waiting", "print_failed", "printer_unreported", "test",
]  # fmt: skip
_GROUP = {"printer_offline": "connection", "klippy_shutdown": "klippy", "klippy_error": "klippy",
          "printer_unreported": "worker"}  # fmt: skip
_MEMBERS_OF = {"storm_offline": "printer_offline"}


def _members(event: FleetEvent) -> list[tuple[str, str]]:
    """(printer id, kind) of each printer an event speaks for (a fold, for each)."""
    kind = _MEMBERS_OF.get(event.kind, event.kind)
    if event.printer is not None:
        return [(event.printer.id, kind)]
    return [(pid, kind) for pid in event.params["printers"]]


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(_P),
            st.sampled_from(_KINDS),
            st.sampled_from(["connection", "klippy", "worker"]),
            st.floats(0, 120),
            st.booleans(),
        ),
        max_size=80,
    ),
    st.sampled_from([0.0, 20.0, 60.0]),
    st.sampled_from([0, 1, 3]),
)
def test_noise_never_repeats_within_cooldown_nor_recovers_what_it_did_not_tell(
    steps: list[tuple[PrinterRef, EventKind, str, float, bool]], fold: float, threshold: int
) -> None:
    cooldown = 300.0
    f = noise(cooldown_s=cooldown, fold_window_s=fold, storm_threshold=threshold)
    last_out: dict[tuple[str, str], float] = {}
    open_alerts: set[tuple[str, str]] = set()
    now = 0.0
    out: list[tuple[float, FleetEvent]] = []
    for who, kind, what, advance, release in steps:
        now += advance
        event = ev(kind, who, what=what) if kind == "printer_recovered" else ev(kind, who)
        out += [(now, e) for e in f.push(event, now)]
        if release:
            out += [(now, e) for e in f.release(now)]
    out += [(now + fold, e) for e in f.release(now + fold)]
    for when, event in out:
        for pid, told in _members(event):
            if told == "test":
                continue
            if told == "printer_recovered":
                key = (pid, event.params["what"])
                assert key in open_alerts, f"{pid}: recovery of {key[1]} with no alert told"
                open_alerts.remove(key)
                continue
            previous = last_out.get((pid, told))
            assert previous is None or when - previous >= cooldown, (pid, told, previous, when)
            last_out[(pid, told)] = when
            if told in _GROUP:
                open_alerts.add((pid, _GROUP[told]))
