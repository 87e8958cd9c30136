"""The detector: a printer's transitions are news, its steady states and first sight are not.

Pure and deterministic: time is the ``now`` passed in. Each transition is shown with the
neighbour that must stay silent (idle vs printing offline, complete seen twice, a restart).
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import kybercore.notify
from kybercore.core.view import LivePrinter
from kybercore.notify.detector import Detector, Observation, observe
from kybercore.notify.models import FleetEvent, NoiseSettings, PrinterRef

T0 = datetime(2026, 5, 1, 22, 0, tzinfo=UTC)
P7 = PrinterRef("printer-7", "Printer 7", "Room B", ("pla",))


def ob(
    state: str | None = "standby",
    connection: str = "online",
    klippy: str = "ready",
    **changes: Any,
) -> Observation:
    fields: dict[str, Any] = {
        "connection": connection,
        "klippy_state": klippy,
        "klippy_message": "",
        "print_state": state,
        "filename": "tower.gcode",
        "print_message": "",
        "layer": None,
        "runout": False,
    }
    fields.update(changes)
    return Observation(**fields)


OFFLINE = ob(connection="offline", klippy="disconnected")


def feed(
    detector: Detector, observations: Iterable[Observation], printer: PrinterRef = P7
) -> list[FleetEvent]:
    """Observe each in turn, one second apart; every event emitted."""
    events = []
    for second, observation in enumerate(observations):
        at = T0 + timedelta(seconds=second)
        events += detector.observe(printer, observation, float(second), at)
    return events


def kinds(events: Iterable[FleetEvent]) -> list[str]:
    return [event.kind for event in events]


def detector(**settings: Any) -> Detector:
    return Detector(NoiseSettings(**settings))


@pytest.mark.parametrize(
    "first",
    [ob("printing"), ob("error"), ob(klippy="shutdown"), OFFLINE, ob(None, "connecting")],
)
def test_the_first_observation_of_a_printer_is_a_baseline(first: Observation) -> None:
    assert feed(detector(), [first]) == []


def test_a_kybercore_restart_in_the_middle_of_a_print_is_silent() -> None:
    # What the session reports after a start: connecting, online before Klippy says
    # anything, then the snapshot (with a print at layer 50) and Klippy ready.
    events = feed(
        detector(),
        [
            ob(None, "connecting", "disconnected"),
            ob(None, klippy="disconnected"),
            ob("printing", klippy="disconnected", layer=50),
            ob("printing", layer=50),
            ob("printing", layer=51),
        ],
    )
    assert events == []


def test_a_restart_finding_klippy_shut_down_is_silent() -> None:
    events = feed(detector(), [ob(None, "connecting", "disconnected"), ob(None, klippy="shutdown")])
    assert events == []


def test_an_idle_printer_going_offline_is_not_news() -> None:
    events = feed(detector(), [ob("standby"), OFFLINE, ob("standby")])
    assert events == []


def test_a_printing_printer_going_offline_sends_one_alert_and_one_recovery() -> None:
    events = feed(detector(), [ob("printing"), OFFLINE, OFFLINE, ob("printing"), ob("printing")])
    assert kinds(events) == ["printer_offline", "printer_recovered"]
    offline, recovered = events
    assert offline.printer == P7
    assert offline.params == {"was": "printing", "filename": "tower.gcode"}
    assert offline.at == T0 + timedelta(seconds=1)
    assert recovered.params == {"what": "connection"}


def test_a_paused_printer_going_offline_says_so() -> None:
    events = feed(detector(), [ob("paused"), ob(connection="connecting", klippy="disconnected")])
    assert [event.params["was"] for event in events] == ["paused"]


def test_the_drop_as_the_session_reports_it_still_alerts() -> None:
    # The session says "Klippy disconnected" before "offline", both while printing.
    events = feed(detector(), [ob("printing"), ob("printing", klippy="disconnected"), OFFLINE])
    assert kinds(events) == ["printer_offline"]


def test_a_reconnect_to_a_print_already_complete_is_not_a_second_completion() -> None:
    events = feed(detector(), [ob("printing"), ob("complete"), OFFLINE, ob("complete")])
    assert kinds(events) == ["print_completed"]


def test_a_print_that_completed_while_offline_is_told_after_the_reconnect() -> None:
    events = feed(detector(), [ob("printing"), OFFLINE, ob("complete")])
    assert kinds(events) == ["printer_offline", "printer_recovered", "print_completed"]


def test_a_reconnect_is_judged_against_the_state_before_the_loss() -> None:
    # The order a real reconnect has: online with the stale status and Klippy unknown,
    # the snapshot (still before Klippy's state), then Klippy ready.
    events = feed(
        detector(),
        [
            ob("printing"),
            OFFLINE,
            ob("printing", klippy="disconnected"),
            ob("complete", klippy="disconnected"),
            ob("complete"),
        ],
    )
    assert kinds(events) == ["printer_offline", "printer_recovered", "print_completed"]


@pytest.mark.parametrize(
    ("before", "after", "kind", "params"),
    [
        ("standby", "printing", "print_started", {}),
        ("complete", "printing", "print_started", {}),
        ("cancelled", "printing", "print_started", {}),
        ("error", "printing", "print_started", {}),
        ("printing", "complete", "print_completed", {}),
        ("paused", "complete", "print_completed", {}),
        ("printing", "error", "print_failed", {"message": "Heater extruder not heating"}),
        ("printing", "cancelled", "print_cancelled", {}),
        ("paused", "cancelled", "print_cancelled", {}),
        ("printing", "paused", "print_paused", {"reason": "unknown"}),
    ],
)
def test_print_state_transitions(
    before: str, after: str, kind: str, params: dict[str, Any]
) -> None:
    message = "Heater extruder not heating"
    events = feed(detector(), [ob(before), ob(after, print_message=message)])
    assert kinds(events) == [kind]
    assert events[0].params == {"filename": "tower.gcode", **params}


@pytest.mark.parametrize(
    ("before", "after"),
    [
        ("paused", "printing"),
        ("standby", "complete"),
        ("complete", "standby"),
        ("standby", "cancelled"),
        ("printing", "standby"),
    ],
)
def test_transitions_that_are_not_news(before: str, after: str) -> None:
    assert feed(detector(), [ob(before), ob(after)]) == []


def test_a_pause_for_runout_says_why() -> None:
    events = feed(detector(), [ob("printing"), ob("paused", runout=True)])
    assert events[0].params["reason"] == "runout"


def test_the_print_state_of_a_klippy_not_ready_is_not_judged() -> None:
    events = feed(detector(), [ob("standby"), ob("printing", klippy="startup"), ob("standby")])
    assert events == []


def test_klippy_shutdown_and_error_alert_and_recover() -> None:
    events = feed(
        detector(),
        [
            ob(),
            ob(klippy="shutdown", klippy_message="MCU 'mcu' shutdown: Timer too close"),
            ob(klippy="disconnected"),
            ob(klippy="startup"),
            ob(),
            ob(klippy="error", klippy_message="Unable to open config file"),
            ob(),
        ],
    )
    assert kinds(events) == [
        "klippy_shutdown",
        "printer_recovered",
        "klippy_error",
        "printer_recovered",
    ]
    assert events[0].params == {"message": "MCU 'mcu' shutdown: Timer too close"}
    assert events[1].params == {"what": "klippy"}


def test_a_klippy_restart_without_a_fault_is_not_news() -> None:
    events = feed(detector(), [ob(), ob(klippy="disconnected"), ob(klippy="startup"), ob()])
    assert events == []


def test_a_printer_lost_after_its_klippy_alert_is_not_a_second_alert() -> None:
    # Shut down mid-print, then power-cycled to recover: the shutdown was the news.
    events = feed(
        detector(),
        [ob("printing"), ob("printing", klippy="shutdown"), OFFLINE, ob("standby")],
    )
    assert kinds(events) == ["klippy_shutdown", "printer_recovered"]
    assert events[1].params == {"what": "klippy"}


def test_the_first_layer_is_done_when_the_layer_passes_one() -> None:
    events = feed(
        detector(),
        [
            ob("standby"),
            ob("printing"),
            ob("printing", layer=1),
            ob("printing", layer=2),
            ob("printing", layer=3),
            ob("paused", layer=3),
            ob("printing", layer=4),
        ],
    )
    assert kinds(events) == ["print_started", "first_layer_done", "print_paused"]
    assert events[1].params == {"filename": "tower.gcode", "layer": 2}


def test_offline_grace_alerts_for_an_idle_printer_offline_long_enough() -> None:
    d = detector(offline_grace_s=600.0)
    assert feed(d, [ob("standby"), OFFLINE]) == []  # lost at now=1.0
    assert d.tick(600.0, T0) == []
    [alert] = d.tick(601.0, T0)
    assert (alert.kind, alert.params, alert.printer) == ("printer_offline", {"minutes": 10}, P7)
    assert d.tick(2000.0, T0) == []
    [recovered] = d.observe(P7, ob("standby"), 2001.0, T0)
    assert recovered.kind == "printer_recovered"


def test_offline_grace_does_not_count_a_short_loss_or_a_printer_never_seen_online() -> None:
    d = detector(offline_grace_s=60.0)
    feed(d, [ob("standby"), OFFLINE, ob("standby")])
    d.observe(PrinterRef("p2", "P2", None, ()), OFFLINE, 0.0, T0)
    assert d.tick(1000.0, T0) == []


def test_without_a_grace_period_an_idle_printer_offline_stays_silent() -> None:
    d = detector()
    feed(d, [ob("standby"), OFFLINE])
    assert d.tick(1e9, T0) == []
    d.update(NoiseSettings(offline_grace_s=60.0))
    assert kinds(d.tick(1e9, T0)) == ["printer_offline"]


UNREPORTED = ob("standby", reported=False)


def test_a_printer_no_worker_reports_past_the_grace_is_told_once_then_its_return() -> None:
    d = detector(unreported_grace_s=30.0)
    assert feed(d, [ob("standby"), UNREPORTED]) == []  # unreported from now=1.0
    assert d.tick(30.9, T0) == []
    [alert] = d.tick(31.0, T0)
    assert (alert.kind, alert.params, alert.printer) == ("printer_unreported", {"seconds": 30}, P7)
    assert alert.severity == "critical"
    assert d.tick(1000.0, T0) == []
    assert d.observe(P7, UNREPORTED, 1001.0, T0) == []
    [back] = d.observe(P7, ob("standby"), 1002.0, T0)
    assert (back.kind, back.params, back.printer) == ("printer_recovered", {"what": "worker"}, P7)
    assert d.observe(P7, ob("standby"), 1003.0, T0) == []


def test_a_printer_unreported_shorter_than_the_grace_is_no_news() -> None:
    # A slot moving between workers: stale for a few seconds, then reported again.
    d = detector(unreported_grace_s=30.0)
    feed(d, [ob("standby"), UNREPORTED])
    assert d.tick(20.0, T0) == []
    assert d.observe(P7, ob("standby"), 21.0, T0) == []
    assert d.tick(1000.0, T0) == []
    # And a second, separate loss counts its grace from its own start.
    assert d.observe(P7, UNREPORTED, 1001.0, T0) == []
    assert d.tick(1030.0, T0) == []
    assert kinds(d.tick(1031.0, T0)) == ["printer_unreported"]


def test_a_printer_unreported_from_the_start_counts_and_a_zero_grace_never_tells() -> None:
    # A front that never heard of a printer has lost sight of it too (unlike offline).
    d = detector(unreported_grace_s=30.0, offline_grace_s=30.0)
    assert d.observe(P7, UNREPORTED, 0.0, T0) == []
    assert kinds(d.tick(30.0, T0)) == ["printer_unreported"]
    silent = detector(unreported_grace_s=0.0)
    silent.observe(P7, UNREPORTED, 0.0, T0)
    assert silent.tick(1e9, T0) == []
    silent.update(NoiseSettings(unreported_grace_s=60.0))
    assert kinds(silent.tick(1e9, T0)) == ["printer_unreported"]


def test_a_printer_unreported_with_its_print_still_running_is_one_alert() -> None:
    # Its last report stands while no worker reports it: nothing else is told; its print
    # ending while unreported is told when a worker reports it again.
    d = detector(unreported_grace_s=30.0)
    feed(d, [ob("printing"), ob("printing", reported=False)])
    assert kinds(d.tick(31.0, T0)) == ["printer_unreported"]
    back = d.observe(P7, ob("complete"), 40.0, T0)
    assert kinds(back) == ["printer_recovered", "print_completed"]


def test_a_forgotten_printer_starts_afresh() -> None:
    d = detector()
    feed(d, [ob("printing")])
    d.forget("printer-7")
    assert d.observe(P7, OFFLINE, 5.0, T0) == []


def test_observe_reads_the_live_state() -> None:
    live = LivePrinter(
        connection="online",
        klippy_state="ready",
        klippy_message="",
        status={
            "print_stats": {
                "state": "paused",
                "filename": "kybercore/j1-c1-a1-tower.gcode",
                "message": "",
                "info": {"current_layer": 3, "total_layer": 90},
            },
            "filament_switch_sensor runout": {"filament_detected": False, "enabled": True},
            "filament_motion_sensor spare": {"filament_detected": True, "enabled": True},
        },
    )
    assert observe(live) == Observation(
        "online", "ready", "", "paused", "kybercore/j1-c1-a1-tower.gcode", "", 3, True
    )


def test_observe_is_not_fooled_by_odd_values() -> None:
    live = LivePrinter(
        status={
            "print_stats": {"state": 3, "filename": None, "message": ["x"], "info": None},
            "filament_switch_sensor off": {"filament_detected": False, "enabled": False},
            "filament_motion_sensor x": {"filament_detected": None},
        }
    )
    got = observe(live)
    assert (got.print_state, got.filename, got.print_message, got.layer, got.runout) == (
        None,
        None,
        "",
        None,
        False,
    )
    live.status["print_stats"]["info"] = {"current_layer": True}
    assert observe(live).layer is None


# --- purity ---------------------------------------------------------------------------------

PURE = ("__init__", "models", "detector", "noise", "rules", "texts")
PURE_MAY_IMPORT = (
    "kybercore.notify", "kybercore.core.view", "kybercore.registry.models",
    "kybercore.moonraker.objects", "__future__", "collections", "dataclasses", "datetime",
    "re", "typing", "uuid",
)  # fmt: skip


def test_the_pure_modules_import_nothing_that_does_io() -> None:
    folder = Path(kybercore.notify.__file__).parent
    found = []
    for name in PURE:
        tree = ast.parse((folder / f"{name}.py").read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                modules = [node.module or ""]
            else:
                continue
            found += [
                f"{name}: {module}"
                for module in modules
                if not any(f"{module}.".startswith(f"{ok}.") for ok in PURE_MAY_IMPORT)
            ]
    assert found == []


# --- property: a recovery always ends an alert ----------------------------------------------

_OBS = st.builds(
    Observation,
    connection=st.sampled_from(["online", "online", "offline", "connecting", "auth_failed"]),
    klippy_state=st.sampled_from(
        ["ready", "ready", "shutdown", "error", "startup", "disconnected"]
    ),
    klippy_message=st.just(""),
    print_state=st.sampled_from([None, "standby", "printing", "paused", "complete", "error"]),
    filename=st.sampled_from([None, "a.gcode"]),
    print_message=st.just(""),
    layer=st.one_of(st.none(), st.integers(0, 3)),
    runout=st.booleans(),
)
_PRINTERS = [P7, PrinterRef("p2", "P2", None, ())]
_STEP = st.one_of(
    st.tuples(st.sampled_from(_PRINTERS), _OBS, st.floats(0, 400)),
    st.tuples(st.none(), st.none(), st.floats(0, 400)),  # a tick
)


@settings(max_examples=300, deadline=None)
@given(st.lists(_STEP, max_size=60), st.sampled_from([0.0, 60.0, 600.0]))
def test_the_detector_never_recovers_what_it_did_not_alert(
    steps: list[tuple[PrinterRef | None, Observation | None, float]], grace: float
) -> None:
    d = detector(offline_grace_s=grace)
    now = 0.0
    open_alerts: set[tuple[str, str]] = set()
    for printer, observation, advance in steps:
        now += advance
        if printer is None or observation is None:
            events = d.tick(now, T0)
        else:
            events = d.observe(printer, observation, now, T0)
        for event in events:
            assert event.printer is not None
            if event.kind == "printer_offline":
                group = "connection"
            elif event.kind in ("klippy_shutdown", "klippy_error"):
                group = "klippy"
            elif event.kind == "printer_recovered":
                key = (event.printer.id, event.params["what"])
                assert key in open_alerts, f"recovery without an alert: {key}"
                open_alerts.remove(key)
                continue
            else:
                continue
            assert (event.printer.id, group) not in open_alerts, "a second alert, unrecovered"
            open_alerts.add((event.printer.id, group))
