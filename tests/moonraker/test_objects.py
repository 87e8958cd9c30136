"""Bookkeeping of a printer's live state from Moonraker's notifications."""

from __future__ import annotations

import copy
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from kybercore.moonraker.objects import (
    apply_status,
    klippy_state_after,
    merge_status,
    status_objects,
    with_klippy_state,
)

FIELDS = st.dictionaries(
    st.sampled_from(["temperature", "target", "position", "info", "state"]),
    st.recursive(
        st.none() | st.floats(allow_nan=False) | st.text(max_size=3),
        lambda inner: (
            st.lists(inner, max_size=3)
            | st.dictionaries(st.sampled_from(["a", "b"]), inner, max_size=2)
        ),
        max_leaves=6,
    ),
    max_size=4,
)
STATUS = st.dictionaries(st.sampled_from(["extruder", "toolhead", "print_stats"]), FIELDS)


def test_a_delta_updates_only_the_fields_it_names() -> None:
    snapshot = {
        "extruder": {"temperature": 20.0, "target": 0.0},
        "print_stats": {"state": "printing", "info": {"current_layer": 1, "total_layer": 9}},
        "toolhead": {"position": [0.0, 0.0, 0.0, 0.0]},
    }
    delta = {
        "extruder": {"temperature": 21.5},
        "print_stats": {"info": {"current_layer": 2}},
        "toolhead": {"position": [1.0, 2.0]},
        "fan": {"speed": 0.5},
    }
    merged = merge_status(snapshot, delta)
    assert merged == {
        "extruder": {"temperature": 21.5, "target": 0.0},
        "print_stats": {"state": "printing", "info": {"current_layer": 2, "total_layer": 9}},
        "toolhead": {"position": [1.0, 2.0]},  # lists replace, they do not merge
        "fan": {"speed": 0.5},
    }


def test_a_merge_makes_new_dicts_only_on_the_deltas_paths() -> None:
    # A front merges every patch of the fleet: copying what a patch does not touch was
    # most of its cost. Sharing is safe because views and patches are never changed.
    snapshot = {
        "job": {"state": "printing", "info": {"current_layer": 3}},
        "bed": {"temperature": 60.0},
    }
    delta = {"job": {"state": "paused"}, "extruder": {"temperature": 20.0}}
    merged = merge_status(snapshot, delta)
    assert merged["job"] == {"state": "paused", "info": {"current_layer": 3}}
    assert merged["job"] is not snapshot["job"]
    assert merged["job"]["info"] is snapshot["job"]["info"]
    assert merged["bed"] is snapshot["bed"]
    assert snapshot["job"]["state"] == "printing"


@given(STATUS, STATUS)
def test_merging_leaves_its_inputs_untouched_and_wins_field_by_field(
    snapshot: dict[str, Any], delta: dict[str, Any]
) -> None:
    before, delta_before = copy.deepcopy(snapshot), copy.deepcopy(delta)
    merged = merge_status(snapshot, delta)
    assert (snapshot, delta) == (before, delta_before)
    assert set(merged) == set(snapshot) | set(delta)
    for obj, fields in delta.items():
        for key, value in fields.items():
            if not isinstance(value, dict):
                assert merged[obj][key] == value
    for obj in set(snapshot) - set(delta):
        assert merged[obj] is snapshot[obj]  # untouched objects are shared, not copied
    # The in-place form the fleet service uses on its own live state gives the same result.
    apply_status(snapshot, delta)
    assert snapshot == merged


def _reference_merge(target: dict[str, Any], new: dict[str, Any]) -> None:
    """The recursive merge apply_status did before its first level was unrolled."""
    for key, value in new.items():
        if type(value) is dict:
            if type(target.get(key)) is not dict:
                target[key] = {}
            _reference_merge(target[key], value)
        else:
            target[key] = value


ODD_STATUS = st.dictionaries(
    st.sampled_from(["extruder", "toolhead", "print_stats"]),
    FIELDS | st.none() | st.integers() | st.lists(st.integers(), max_size=2),
)


@given(ODD_STATUS, ODD_STATUS)
def test_the_in_place_merge_is_the_recursive_one_whatever_the_peer_sends(
    status: dict[str, Any], delta: dict[str, Any]
) -> None:
    expected = copy.deepcopy(status)
    _reference_merge(expected, copy.deepcopy(delta))
    apply_status(status, delta)
    assert status == expected


def test_status_objects_drops_what_is_not_an_object_and_copies_only_then() -> None:
    clean = {"extruder": {"temperature": 1.0}, "fan": {}}
    assert status_objects(clean) is clean  # the per-update path: no copy
    odd = {"extruder": {"temperature": 1.0}, "junk": 3, "list": [1]}
    assert status_objects(odd) == {"extruder": {"temperature": 1.0}}
    assert odd["junk"] == 3  # the input is left as it was


def test_klippy_state_follows_notifications_and_webhooks() -> None:
    assert klippy_state_after("ready", "notify_klippy_shutdown") == "shutdown"
    assert klippy_state_after("shutdown", "notify_klippy_ready") == "ready"
    assert klippy_state_after("ready", "notify_klippy_disconnected") == "disconnected"
    update = [{"webhooks": {"state": "error"}}]
    assert klippy_state_after("ready", "notify_status_update", update) == "error"
    assert klippy_state_after("ready", "notify_status_update", [{"webhooks": {}}]) == "ready"
    bogus = [{"webhooks": {"state": "exploded"}}]
    assert klippy_state_after("ready", "notify_status_update", bogus) == "ready"
    assert klippy_state_after("ready", "notify_gcode_response", ["ok"]) == "ready"


def test_a_subscription_always_says_klippys_state() -> None:
    assert with_klippy_state({"extruder": None}) == {"extruder": None, "webhooks": ["state"]}
    assert with_klippy_state({"webhooks": ["state_message"]}) == {
        "webhooks": ["state_message", "state"]
    }
    assert with_klippy_state({"webhooks": None}) == {"webhooks": None}
    assert with_klippy_state({"webhooks": ["state"]}) == {"webhooks": ["state"]}
