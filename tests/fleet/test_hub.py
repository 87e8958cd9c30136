"""The browser fan-out: snapshots, coalesced deltas, events, slow clients."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import pytest

from kybercore.fleet import hub as fleet_hub
from kybercore.fleet.hub import QUEUE_FRAMES, Hub, HubClient
from kybercore.moonraker.objects import merge_status


class Fleet:
    """Views a test can change, rendered by the hub on demand."""

    def __init__(self) -> None:
        self.views: dict[str, dict[str, Any]] = {}
        self.renders = 0

    def render(self, printer_id: str) -> dict[str, Any] | None:
        self.renders += 1
        view = self.views.get(printer_id)
        return None if view is None else json.loads(json.dumps(view))


def frames(client: HubClient) -> list[dict[str, Any]]:
    out = []
    while not client.queue.empty():
        out.append(json.loads(client.queue.get_nowait()))
    return out


def test_first_frame_is_a_snapshot_then_deltas() -> None:
    fleet = Fleet()
    hub = Hub(fleet.render)
    fleet.views["a"] = {"id": "a", "extruder": {"temperature": 20.0, "target": 0.0}}
    hub.mark("a")
    client = hub.connect()
    [snapshot] = frames(client)
    assert snapshot["type"] == "snapshot"
    assert snapshot["printers"] == [fleet.views["a"]]

    fleet.views["a"]["extruder"]["temperature"] = 21.0
    hub.mark("a")
    hub.flush()
    [delta] = frames(client)
    assert delta["type"] == "delta"
    assert delta["printers"] == {"a": {"extruder": {"temperature": 21.0}}}
    assert delta["seq"] == snapshot["seq"] + 1


def test_patches_made_elsewhere_are_passed_on_without_rendering() -> None:
    # A front forwards its workers' patches: the same frames as a render, no render.
    fleet = Fleet()
    hub = Hub(fleet.render)
    client = hub.connect()
    frames(client)
    first = {"id": "a", "extruder": {"temperature": 20.0, "target": 0.0}}
    hub.patched("a", first, first)
    second = {"id": "a", "extruder": {"temperature": 21.0, "target": 0.0}}
    hub.patched("a", second, {"extruder": {"temperature": 21.0}})
    third = {"id": "a", "extruder": {"temperature": 21.0, "target": 60.0}}
    hub.patched("a", third, {"extruder": {"target": 60.0}})
    hub.flush()
    [delta] = frames(client)
    # A new printer's first patch is its view; later ones in the same tick merge into it.
    assert delta["printers"] == {"a": third}
    hub.patched("a", second, {"extruder": {"target": 0.0}})
    hub.flush()
    [delta] = frames(client)
    assert delta["printers"] == {"a": {"extruder": {"target": 0.0}}}
    assert hub.view("a") == second
    assert json.loads(hub.fleet_json()) == [second]
    assert fleet.renders == 0


def test_many_updates_in_one_tick_become_one_frame() -> None:
    fleet = Fleet()
    hub = Hub(fleet.render)
    client = hub.connect()
    frames(client)
    for step in range(100):
        for printer in ("a", "b", "c"):
            fleet.views[printer] = {"id": printer, "progress": step}
            hub.mark(printer)
    hub.flush()
    [delta] = frames(client)
    assert delta["printers"] == {p: {"id": p, "progress": 99} for p in "abc"}
    assert fleet.renders == 3


def test_nothing_changed_sends_nothing() -> None:
    fleet = Fleet()
    fleet.views["a"] = {"id": "a"}
    hub = Hub(fleet.render)
    hub.mark("a")
    client = hub.connect()
    frames(client)
    hub.mark("a")
    hub.flush()
    assert frames(client) == []


def test_removed_printers_are_announced() -> None:
    fleet = Fleet()
    fleet.views["a"] = {"id": "a"}
    hub = Hub(fleet.render)
    hub.mark("a")
    client = hub.connect()
    frames(client)
    del fleet.views["a"]
    hub.mark("a")
    hub.flush()
    [delta] = frames(client)
    assert delta["removed"] == ["a"]


def test_events_reach_everyone_and_console_only_subscribers() -> None:
    hub = Hub(Fleet().render)
    watcher, other = hub.connect(), hub.connect()
    frames(watcher)
    frames(other)
    watcher.console = {"a"}
    hub.event({"type": "action", "printer": "a", "ok": True})
    hub.console("a", "ok T:20")
    hub.flush()
    assert [f["type"] for f in frames(watcher)] == ["gcode_response", "action"]
    assert [f["type"] for f in frames(other)] == ["action"]


def test_a_slow_client_gets_a_fresh_snapshot_and_does_not_hold_others() -> None:
    fleet = Fleet()
    hub = Hub(fleet.render)
    slow, fast = hub.connect(), hub.connect()
    frames(fast)
    for step in range(QUEUE_FRAMES + 5):
        fleet.views["a"] = {"id": "a", "progress": step}
        hub.mark("a")
        hub.flush()
        frames(fast)  # the fast client keeps up
    assert slow.resyncs >= 1
    received = frames(slow)
    assert len(received) <= QUEUE_FRAMES
    # Whatever it missed, replaying what it has ends at the current state.
    state: dict[str, Any] = {}
    for frame in received:
        if frame["type"] == "snapshot":
            state = {p["id"]: p for p in frame["printers"]}
        else:
            for pid, patch in frame["printers"].items():
                state.setdefault(pid, {}).update(patch)
    assert state == {"a": {"id": "a", "progress": QUEUE_FRAMES + 4}}


def test_disconnected_clients_get_nothing() -> None:
    fleet = Fleet()
    hub = Hub(fleet.render)
    client = hub.connect()
    hub.disconnect(client)
    frames(client)
    fleet.views["a"] = {"id": "a"}
    hub.mark("a")
    hub.flush()
    assert frames(client) == []
    assert hub.client_count == 0


def test_the_fleet_list_is_the_published_views_and_follows_every_flush() -> None:
    fleet = Fleet()
    hub = Hub(fleet.render)
    for printer in ("a", "b", "c"):
        fleet.views[printer] = {"id": printer, "progress": 0}
        hub.mark(printer)
    hub.flush()
    assert json.loads(hub.fleet_json()) == [fleet.views[p] for p in ("a", "b", "c")]
    assert hub.fleet_json() is hub.fleet_json()  # one body for every reader of a tick

    fleet.views["b"]["progress"] = 7
    del fleet.views["c"]
    hub.mark("b")
    hub.mark("c")
    assert json.loads(hub.fleet_json())[1]["progress"] == 0  # not published yet
    hub.flush()
    assert json.loads(hub.fleet_json()) == [fleet.views["a"], fleet.views["b"]]
    assert hub.views() == [fleet.views["a"], fleet.views["b"]]
    client = hub.connect()
    [snapshot] = frames(client)
    assert snapshot["printers"] == [fleet.views["a"], fleet.views["b"]]


async def test_a_tick_renders_in_slices_and_a_flush_between_them_loses_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(fleet_hub, "SLICE_SECONDS", 0.0)  # one printer per slice
    fleet = Fleet()

    def change_a_again_and_flush() -> None:
        # Runs while the tick yields between its slices, as a request or a browser
        # connecting would: it publishes before the tick does.
        fleet.views["a"].update(progress=2, temp=5)
        hub.mark("a")
        hub.flush()

    def render(printer_id: str) -> dict[str, Any] | None:
        if printer_id == "a" and fleet.views["a"]["progress"] == 1:
            asyncio.get_running_loop().call_soon(change_a_again_and_flush)
        return fleet.render(printer_id)

    hub = Hub(render, tick=0.01)
    for printer in ("a", "b"):
        fleet.views[printer] = {"id": printer, "progress": 0, "temp": 0, "layer": 0}
        hub.mark(printer)
    client = hub.connect()
    state = {p["id"]: p for p in frames(client)[0]["printers"]}
    fleet.views["a"].update(progress=1, layer=1)
    fleet.views["b"]["progress"] = 1
    hub.mark("a")
    hub.mark("b")
    hub.start()
    try:
        for _ in range(100):
            await asyncio.sleep(0.01)  # poll: wait for the state to converge, 100 tries
            for frame in frames(client):
                state = merge_status(state, frame["printers"])
            if state == fleet.views:
                break
    finally:
        await hub.stop()
    assert state["a"] == {"id": "a", "progress": 2, "temp": 5, "layer": 1}
    assert state["b"] == fleet.views["b"]


def test_a_refreshed_printer_is_read_at_once_and_sent_with_the_next_frame() -> None:
    fleet = Fleet()
    hub = Hub(fleet.render)
    fleet.views["a"] = {"id": "a", "job": {"state": "standby"}}
    fleet.views["b"] = {"id": "b", "job": {"state": "standby"}}
    hub.mark("a")
    hub.mark("b")
    client = hub.connect()
    frames(client)
    for state in ("printing", "paused"):  # two actions answered within one tick
        fleet.views["a"]["job"]["state"] = state
        hub.refresh("a")
        assert hub.view("a") == fleet.views["a"]
        assert json.loads(hub.fleet_json())[0]["job"]["state"] == state
    assert frames(client) == []  # browsers get it with the tick, not a frame per action
    hub.flush()
    [delta] = frames(client)
    assert delta["printers"] == {"a": {"job": {"state": "paused"}}}
