"""Pure bookkeeping of one printer's live state, fed by Moonraker notifications.

No I/O here: the WebSocket session calls these functions with what it received, and tests
call them with plain dicts.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

Status = dict[str, dict[str, Any]]
"""Printer objects as Moonraker reports them: ``{"extruder": {"temperature": 21.3}, ...}``."""

KLIPPY_STATES: Final = frozenset({"ready", "startup", "shutdown", "error", "disconnected"})

# Which Klippy state each Moonraker notification implies.
_NOTIFICATION_STATES: Final = {
    "notify_klippy_ready": "ready",
    "notify_klippy_shutdown": "shutdown",
    "notify_klippy_disconnected": "disconnected",
}


def merge_status(snapshot: Mapping[str, Any], delta: Mapping[str, Any]) -> dict[str, Any]:
    """Return ``snapshot`` deep-merged with ``delta`` (a ``notify_status_update`` delta, or
    a patch of a fused view); both are left untouched. Only the dicts on the delta's paths
    are new: what the delta does not name is shared with ``snapshot``, and what it brings
    is shared with ``delta``, so neither input may be changed in place afterwards (views
    and patches never are)."""
    # Copy on write, not a deep copy of each object named: a front merges every patch of
    # the fleet, and copy.deepcopy made that 8x slower.
    merged = dict(snapshot)
    for key, value in delta.items():
        old = merged.get(key)
        merged[key] = (
            merge_status(old, value) if type(value) is dict and type(old) is dict else value
        )
    return merged


def apply_status(status: Status, delta: Mapping[str, Mapping[str, Any]]) -> None:
    """Update ``status`` in place with a ``notify_status_update`` delta.

    Moonraker sends only the fields that changed, so nested dicts are merged key by key;
    anything else (lists such as ``toolhead.position`` included) replaces the old value.
    In place because this runs for every update of every printer: copying the printer's
    objects on each one was a tenth of the ingest cost at 20,000 updates/s.
    """
    # Typed loosely: whatever a peer sent may be there, and compiled (kybercore/native.py)
    # each value read from a ``Status`` would be checked to be a dict.
    loose: dict[str, Any] = status
    # The first level by hand: one call per object in the delta was a third of the merge.
    for name, fields in delta.items():
        objects = loose.get(name)
        if type(fields) is not dict or type(objects) is not dict:
            _merge_into(status, {name: fields})
            continue
        for key, value in fields.items():
            if type(value) is dict:
                _merge_into(objects, {key: value})
            else:
                objects[key] = value


def _merge_into(target: dict[str, Any], new: Mapping[str, Any]) -> None:
    for key, value in new.items():
        # Exact dict checks: the data is decoded JSON, and an ABC isinstance check per field
        # is measurable at this rate.
        if type(value) is dict:
            previous = target.get(key)
            if type(previous) is not dict:
                target[key] = previous = {}
            _merge_into(previous, value)
        else:
            target[key] = value


def klippy_state_after(current: str, method: str, params: list[Any] | None = None) -> str:
    """The Klippy state after Moonraker sends notification ``method``.

    ``notify_status_update`` may carry ``webhooks.state``, which is authoritative; other
    notifications leave the state as it was.
    """
    if method in _NOTIFICATION_STATES:
        return _NOTIFICATION_STATES[method]
    if method == "notify_status_update" and params and isinstance(params[0], Mapping):
        return klippy_state_in(params[0]) or current
    return current


def klippy_state_in(status: Mapping[str, Any]) -> str | None:
    """Klippy's state as a status or delta carries it (``webhooks.state``), if it does."""
    webhooks = status.get("webhooks")
    if isinstance(webhooks, Mapping):
        state = webhooks.get("state")
        if isinstance(state, str) and state in KLIPPY_STATES:
            return state
    return None


def status_objects(status: Mapping[str, Any]) -> Status:
    """The printer objects of a status or delta that are objects (``{name: {field: ...}}``);
    anything else a broken or hostile peer sends is dropped, so consumers can merge safely.
    When every entry is an object (always, from a sane Moonraker), ``status`` itself."""
    for fields in status.values():
        if type(fields) is not dict:
            return {name: fields for name, fields in status.items() if isinstance(fields, dict)}
    # Not copied: this runs for every update, and the decoded message is the caller's alone.
    return status  # type: ignore[return-value]


def snapshot_status(result: Any) -> Status | None:
    """The status in a ``printer.objects.subscribe`` (or query) answer; ``None`` if none."""
    status = result.get("status") if isinstance(result, dict) else None
    return status_objects(status) if isinstance(status, dict) else None


def with_klippy_state(
    subscription: Mapping[str, list[str] | None],
) -> dict[str, list[str] | None]:
    """``subscription`` with ``webhooks.state`` in it: every snapshot and delta then says
    Klippy's state, which is how the session follows it."""
    objects = dict(subscription)
    fields = objects.get("webhooks", [])
    if fields is not None and "state" not in fields:
        objects["webhooks"] = [*fields, "state"]
    return objects
