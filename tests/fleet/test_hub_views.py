"""Browsers that say which printers they show: full views of those, slim summaries of the
rest, and encodings shared between clients."""

from __future__ import annotations

import json
from typing import Any

import pytest

from kybercore.fleet import hub as fleet_hub
from kybercore.fleet.frames import DeltaFrames, slim
from kybercore.fleet.hub import QUEUE_FRAMES, Hub, HubClient
from kybercore.moonraker.objects import merge_status
from tests.fleet.test_hub import Fleet, frames


def printer(printer_id: str, temperature: float = 20.0, progress: float = 0.0) -> dict[str, Any]:
    """A view shaped like :func:`kybercore.core.view.fuse`'s, reduced to a few fields."""
    return {
        "id": printer_id,
        "name": printer_id.upper(),
        "tags": ["pla"],
        "connection": "online",
        "klippy_state": "ready",
        "job": {"state": "printing", "progress": progress, "eta_seconds": 60, "layer": 3},
        "spool": {"id": 7, "material": "PLA", "remaining_g": 612.0},
        "spoolman": "active",
        "extruder": {"temperature": temperature, "target": 210.0},
        "updated_at": 1.0 + temperature,
    }


def fleet_of(*ids: str) -> tuple[Fleet, Hub]:
    fleet = Fleet()
    hub = Hub(fleet.render)
    for printer_id in ids:
        fleet.views[printer_id] = printer(printer_id)
        hub.mark(printer_id)
    hub.flush()
    return fleet, hub


def apply(state: dict[str, Any], frame: dict[str, Any]) -> dict[str, Any]:
    """What the dashboard's store does with a frame."""
    if frame["type"] == "snapshot":
        state = {p["id"]: p for p in frame["printers"]}
        return merge_status(state, {p["id"]: p for p in frame.get("full", [])})
    if frame["type"] == "views":
        return {**state, **{p["id"]: p for p in frame["printers"]}}
    state = merge_status(merge_status(state, frame["printers"]), frame.get("full", {}))
    return {k: v for k, v in state.items() if k not in frame["removed"]}


def test_the_slim_summary_keeps_what_the_dashboard_sorts_by_and_drops_the_rest() -> None:
    summary = slim(printer("a"))
    assert summary == {
        "id": "a",
        "name": "A",
        "tags": ["pla"],
        "connection": "online",
        "klippy_state": "ready",
        "job": {"state": "printing", "progress": 0.0, "eta_seconds": 60},
        "spool": {"id": 7, "material": "PLA", "remaining_g": 612.0},
        "spoolman": "active",
    }
    assert slim({"extruder": {"temperature": 21.0}, "job": {"layer": 4}}) == {}


def test_full_patches_in_view_slim_summaries_outside() -> None:
    fleet, hub = fleet_of("a", "b", "c")
    client = hub.connect()
    hub.watch(client, ["a"])
    [snapshot] = frames(client)
    state = apply({}, snapshot)
    assert state == {p: fleet.views[p] for p in "abc"}  # connected with no view: all full

    for p in "abc":
        fleet.views[p] = printer(p, temperature=25.0, progress=0.5)
        hub.mark(p)
    hub.flush()
    [delta] = frames(client)
    assert delta["full"] == {
        "a": {"extruder": {"temperature": 25.0}, "updated_at": 26.0, "job": {"progress": 0.5}}
    }
    assert delta["printers"] == {p: {"job": {"progress": 0.5}} for p in "abc"}
    state = apply(state, delta)
    assert state["a"] == fleet.views["a"]
    assert state["b"]["job"]["progress"] == 0.5
    assert state["b"]["extruder"]["temperature"] == 20.0  # not followed out of view


def test_a_client_connecting_with_a_view_gets_that_views_snapshot_first() -> None:
    fleet, hub = fleet_of("a", "b", "c")
    client = hub.connect(["b", "gone"])  # an id no longer in the fleet is ignored
    [snapshot] = frames(client)
    assert snapshot["printers"] == [slim(fleet.views[p]) for p in "abc"]
    assert snapshot["full"] == [fleet.views["b"]]
    hub.watch(client, ["b", "gone"])  # what the page says again once open: nothing new
    assert frames(client) == []
    fleet.views["c"]["extruder"]["temperature"] = 30.0
    fleet.views["b"]["extruder"]["temperature"] = 31.0
    for p in "bc":
        hub.mark(p)
    hub.flush()
    [delta] = frames(client)
    assert delta["printers"] == {}
    assert delta["full"] == {"b": {"extruder": {"temperature": 31.0}}}
    [none_in_full] = frames(hub.connect([]))
    assert none_in_full["full"] == []
    assert none_in_full["printers"] == [slim(fleet.views[p]) for p in "abc"]


def test_a_change_outside_the_view_costs_an_empty_delta_only() -> None:
    fleet, hub = fleet_of("a", "b")
    client = hub.connect()
    hub.watch(client, ["a"])
    [snapshot] = frames(client)
    fleet.views["b"]["extruder"]["temperature"] = 30.0
    hub.mark("b")
    hub.flush()
    [delta] = frames(client)
    # Still sent: the browser checks that no sequence number is missing.
    assert delta == {
        "type": "delta",
        "seq": snapshot["seq"] + 1,
        "removed": [],
        "printers": {},
        "full": {},
    }


def test_a_printer_entering_the_view_is_sent_in_full_at_once() -> None:
    fleet, hub = fleet_of("a", "b", "c")
    client = hub.connect()
    hub.watch(client, ["a"])
    frames(client)
    hub.watch(client, ["a", "b"])
    [views] = frames(client)
    assert views == {"type": "views", "printers": [fleet.views["b"]]}
    hub.watch(client, ["a", "b"])
    assert frames(client) == []  # the same view again: nothing new
    hub.watch(client, None)
    [views] = frames(client)
    assert views["printers"] == [fleet.views["c"]]


def test_a_slow_client_with_a_view_resyncs_with_full_views_of_it_only() -> None:
    fleet, hub = fleet_of("a", "b")
    client = hub.connect()
    hub.watch(client, ["b"])
    frames(client)
    for step in range(QUEUE_FRAMES + 1):
        fleet.views["a"]["extruder"]["temperature"] = float(step)
        hub.mark("a")
        hub.flush()
    [snapshot] = frames(client)
    assert client.resyncs == 1
    assert snapshot["type"] == "snapshot"
    assert snapshot["printers"] == [slim(fleet.views["a"]), slim(fleet.views["b"])]
    assert snapshot["full"] == [fleet.views["b"]]
    assert apply({}, snapshot) == {"a": slim(fleet.views["a"]), "b": fleet.views["b"]}


def overflow(hub: Hub, client: HubClient) -> dict[str, Any]:
    """Fill the client's queue as a browser that stopped reading would, so the next frame
    overflows it; return the snapshot that replaces its backlog."""
    while not client.queue.full():
        client.queue.put_nowait(b"{}")
    hub.event({"type": "tick"})
    hub.flush()
    [snapshot] = frames(client)
    assert snapshot["type"] == "snapshot"
    return snapshot


def test_resent_summaries_follow_every_change_without_deriving_them_again(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fleet, hub = fleet_of("a", "b", "c")
    client = hub.connect()
    hub.watch(client, ["b"])
    assert [p["id"] for p in overflow(hub, client)["printers"]] == ["a", "b", "c"]
    derived = []
    monkeypatch.setattr(fleet_hub, "slim", lambda view: derived.append(view) or slim(view))

    changes = [
        ("a", lambda: fleet.views["a"]["job"].update(progress=0.5)),  # in every summary
        ("c", lambda: fleet.views["c"]["extruder"].update(temperature=99.0)),  # in none
        ("d", lambda: fleet.views.update(d=printer("d", progress=0.2))),  # a new printer
        ("b", lambda: fleet.views.pop("b")),  # a printer removed, the one in view
        ("a", lambda: fleet.views["a"].update(name="Alpha", klippy_state="shutdown")),
    ]
    for printer_id, change in changes:
        change()
        hub.mark(printer_id)
        hub.flush()
        snapshot = overflow(hub, client)
        assert snapshot["printers"] == [slim(view) for view in fleet.views.values()]
        assert snapshot["full"] == [fleet.views[i] for i in ["b"] if i in fleet.views]
    assert derived == []  # kept from the deltas' slim patches, not derived from the views


def test_clients_share_encodings_instead_of_one_each() -> None:
    fleet, hub = fleet_of(*"abcd")
    everything = [hub.connect() for _ in range(3)]
    page_one = [hub.connect() for _ in range(3)]
    page_two = hub.connect()
    for client in page_one:
        hub.watch(client, ["a", "b"])
    hub.watch(page_two, ["c", "d"])
    for client in [*everything, *page_one, page_two]:
        frames(client)
    fleet.views["a"]["extruder"]["temperature"] = 40.0
    fleet.views["c"]["job"]["progress"] = 0.7
    hub.mark("a")
    hub.mark("c")
    hub.flush()

    def raw(client: HubClient) -> bytes:
        [frame] = [client.queue.get_nowait()]
        return frame

    sent = {client.id: raw(client) for client in [*everything, *page_one, page_two]}
    assert len({id(sent[c.id]) for c in everything}) == 1
    assert len({id(sent[c.id]) for c in page_one}) == 1
    assert json.loads(sent[page_two.id])["full"] == {"c": {"job": {"progress": 0.7}}}


def test_a_delta_encodes_patches_once_per_need() -> None:
    patches = {p: {"job": {"progress": 0.1}, "extruder": {"temperature": 1.0}} for p in "abc"}
    delta = DeltaFrames(1, patches, [])
    for _ in range(5):
        delta.frame(None)
        delta.frame(frozenset({"a"}))
        delta.frame(frozenset({"a", "x"}))  # the same changed printers in view: same frame
        delta.frame(frozenset({"b"}))
    # The full patches once, the slim ones once (spliced with each view's own full patches).
    assert delta.encodings == 2
    assert delta.frame(frozenset({"a"})) is delta.frame(frozenset({"a", "x"}))
    assert json.loads(delta.frame(frozenset({"b"}))) == {
        "type": "delta",
        "seq": 1,
        "removed": [],
        "printers": {p: {"job": {"progress": 0.1}} for p in "abc"},
        "full": {"b": patches["b"]},
    }
