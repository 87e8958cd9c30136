"""The spool map and the low-filament mark: pure, from the printers' views."""

from __future__ import annotations

from typing import Any

from kybercore.core.spools import LOW_FILAMENT_G, Spool, spool_map


def _spool(spool_id: int, grams: float | None) -> Spool:
    return Spool(spool_id, "Acme Basic PLA", "PLA", "D62828", grams)


def _view(pid: str, shown: Spool | None, spoolman: str = "active") -> dict[str, Any]:
    return {"id": pid, "name": pid.upper(), "spool": shown.public if shown else None,
            "spoolman": spoolman}  # fmt: skip


def test_a_spool_is_low_below_the_threshold_and_never_when_its_weight_is_unknown() -> None:
    assert _spool(1, LOW_FILAMENT_G - 0.1).low
    assert not _spool(1, LOW_FILAMENT_G).low
    assert not _spool(1, None).low
    assert _spool(1, 12.0).public["low"] is True


def test_the_map_puts_each_spool_with_its_printers_fewest_grams_first() -> None:
    full, short, unknown = _spool(1, 800.0), _spool(2, 25.0), _spool(3, None)
    mapped = spool_map([
        _view("a", full), _view("b", unknown), _view("c", short),
        _view("d", None, "absent"), _view("e", None, "none"),
    ])  # fmt: skip
    assert [(s["id"], s["printers"]) for s in mapped["spools"]] == [
        (2, [{"id": "c", "name": "C"}]),
        (1, [{"id": "a", "name": "A"}]),
        (3, [{"id": "b", "name": "B"}]),  # weight unknown: last
    ]
    assert mapped["spools"][0]["material"] == "PLA"
    assert mapped["spools"][0]["low"] is True
    assert mapped["without"] == [
        {"id": "d", "name": "D", "spoolman": "absent"},
        {"id": "e", "name": "E", "spoolman": "none"},
    ]
    assert mapped["low_below_g"] == LOW_FILAMENT_G


def test_one_spool_set_active_on_two_printers_is_one_entry_naming_both() -> None:
    one = _spool(5, 300.0)
    mapped = spool_map([_view("a", one), _view("b", one)])
    assert [p["id"] for p in mapped["spools"][0]["printers"]] == ["a", "b"]
    assert "printers" not in one.public  # the view's cached dict is not touched


def test_a_view_from_before_spoolman_states_counts_as_unknown() -> None:
    assert spool_map([{"id": "a", "name": "A", "spool": None}])["without"] == [
        {"id": "a", "name": "A", "spoolman": "unknown"}
    ]
