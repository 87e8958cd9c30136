"""A front's ``/metrics`` from its views, without a broker: each printer's state as its
owner's timeline names it, and a stale printer counted as such without its last readings."""

from __future__ import annotations

from typing import Any

from kybercore.ledger.metrics import QueueFigures, Snapshot, exposition
from kybercore.scale.front_metrics import printer_states
from tests.metrics_scrape import by_state, parse


def view(printer: str, connection: str, klippy: str = "ready", job: str = "") -> dict[str, Any]:
    heater = {"temperature": 21.5, "target": 0.0}
    return {
        "id": printer, "connection": connection, "klippy_state": klippy,
        "job": {"state": job, "progress": 0.25}, "extruder": heater, "bed": heater,
    }  # fmt: skip


VIEWS = [
    view("a", "online", job="printing"),
    view("b", "online", job="complete"),
    view("c", "stale", job="printing"),
    view("d", "connecting", klippy="disconnected"),
    view("e", "online", klippy="shutdown"),
]


def test_each_printer_is_named_as_its_owners_timeline_would_and_stale_as_stale() -> None:
    gates = {"b": "awaiting_clear", "c": "maintenance", "d": "maintenance"}
    assert printer_states(VIEWS, gates) == {
        "a": "printing",
        "b": "awaiting_clear",
        "c": "stale",  # whatever its gate: nobody reports the printer now
        "d": "maintenance",
        "e": "error",
    }


def test_a_stale_printer_is_counted_under_stale_without_its_last_readings() -> None:
    snapshot = Snapshot(
        views=VIEWS,
        states=printer_states(VIEWS, {}),
        jobs={("a", "completed"): 2},
        queue=QueueFigures(),
        reconnects={},
        browsers=1,
        loop_lag=0.0,
    )
    text = exposition(snapshot).decode()
    samples = parse(text)
    assert by_state(samples) == {
        "online/ready": 2, "stale/ready": 1, "connecting/disconnected": 1, "online/shutdown": 1,
    }  # fmt: skip
    for name in ("kybercore_heater_temperature_celsius", "kybercore_print_progress_ratio"):
        printers = {dict(labels)["printer"] for labels in samples[name]}
        assert printers == {"a", "b", "d", "e"}, name
    assert samples["kybercore_printer_state"][(("printer", "c"), ("state", "stale"))] == 1
    assert samples["kybercore_jobs_total"] == {(("outcome", "completed"), ("printer", "a")): 2}
    # No reconnects on a front, and the family says why.
    assert "kybercore_moonraker_reconnects_total" not in samples
    assert "none on a front on NATS" in text


def test_each_worker_a_front_hears_is_shown_with_its_slots_and_loop_lag() -> None:
    shown = Snapshot(
        views=[], states={}, jobs={}, queue=QueueFigures(), reconnects={}, browsers=0,
        loop_lag=0.0, workers={"w1": (40, 0.012), "w2": (24, 1.25)}, broker_connected=False,
    )  # fmt: skip
    samples = parse(exposition(shown).decode())
    assert samples["kybercore_broker_connected"] == {(): 0}
    assert samples["kybercore_worker_slots"] == {(("worker", "w1"),): 40, (("worker", "w2"),): 24}
    assert samples["kybercore_worker_event_loop_lag_seconds"] == {
        (("worker", "w1"),): 0.012,
        (("worker", "w2"),): 1.25,
    }
