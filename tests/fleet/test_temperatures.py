"""The heaters' ring buffer: one sample a second, held values, gaps, a bounded window."""

from __future__ import annotations

import pytest

from kybercore.fleet.temperatures import CAPACITY, WINDOW_SECONDS, Temperatures


class Clock:
    def __init__(self, now: float = 1_000_000.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def heater(temperature: float, target: float = 0.0) -> dict[str, float]:
    return {"temperature": temperature, "target": target}


def test_updates_within_a_second_keep_one_sample_the_latest() -> None:
    clock = Clock()
    temps = Temperatures(clock)
    for step, value in enumerate((20.0, 21.0, 22.0, 23.0)):
        clock.now = 1_000_000.0 + step * 0.25  # Moonraker's four pushes a second
        status = {"extruder": heater(value, 200)}
        temps.feed("p", status, status)
    series = temps.series("p")["extruder"]
    assert series["temperature"] == [23.0]
    assert series["target"] == [200.0]


def test_a_heater_that_sends_nothing_holds_its_value_until_now() -> None:
    clock = Clock()
    temps = Temperatures(clock)
    status = {"extruder": heater(21.5), "heater_bed": heater(22.0, 60)}
    temps.feed("p", status, status)
    clock.now += 1.5
    status["extruder"] = heater(30.0)
    temps.feed("p", status, {"extruder": status["extruder"]})  # the bed did not change
    clock.now += 120
    series = temps.series("p")
    assert series["extruder"]["temperature"] == [21.5, 30.0, 30.0]
    assert series["extruder"]["t"][-1] == clock.now
    assert series["heater_bed"]["temperature"] == [22.0, 22.0]
    assert series["heater_bed"]["target"] == [60.0, 60.0]


def test_a_gap_ends_the_series_and_nothing_is_held_across_it() -> None:
    clock = Clock()
    temps = Temperatures(clock)
    status = {"extruder": heater(50.0, 60)}
    temps.feed("p", status, status)
    clock.now += 5
    temps.gap("p")  # offline
    temps.gap("p")  # a second notice adds nothing
    clock.now += 60
    series = temps.series("p")["extruder"]
    assert series["temperature"] == [50.0, None]
    assert series["target"] == [60.0, None]


def test_only_the_window_asked_for_and_never_more_than_capacity() -> None:
    clock = Clock()
    temps = Temperatures(clock)
    for second in range(WINDOW_SECONDS * 2):
        clock.now = 1_000_000.0 + second
        status = {"extruder": heater(20 + second % 7)}
        temps.feed("p", status, status)
    full = temps.series("p")["extruder"]
    assert len(full["t"]) == WINDOW_SECONDS + 1  # the window's samples, inclusive
    assert full["t"][0] == clock.now - WINDOW_SECONDS
    assert len(temps.series("p", minutes=2)["extruder"]["t"]) == 121
    assert temps._printers["p"]["extruder"].count == CAPACITY


def test_deltas_without_heaters_and_removed_printers_leave_nothing() -> None:
    temps = Temperatures(Clock())
    temps.feed("p", {"toolhead": {"position": [0, 0, 0, 0]}}, {"toolhead": {}})
    assert temps.series("p") == {}
    status = {"extruder": heater(20.0)}
    temps.feed("p", status, status)
    temps.forget("p")
    assert temps.series("p") == {}


def test_odd_values_are_read_as_before_the_fast_path() -> None:
    # Ints are numbers; a bool or text is not a temperature; an odd target reads as 0.
    clock = Clock()
    temps = Temperatures(clock)
    for step, fields in enumerate(
        (
            {"temperature": 20, "target": 200},
            {"temperature": True, "target": 200.0},
            {"temperature": "hot", "target": 200.0},
            {"temperature": 21.5, "target": False},
            {"temperature": 22.5, "target": None},
        )
    ):
        clock.now = 1_000_000.0 + step  # one sample a second
        status = {"extruder": fields, "heater_bed": "not an object"}
        temps.feed("p", status, status)
    assert set(temps.series("p")) == {"extruder"}
    series = temps.series("p")["extruder"]
    assert series["temperature"] == [20.0, 21.5, 22.5]
    assert series["target"] == [200.0, 0.0, 0.0]
    assert series["t"] == [1_000_000.0, 1_000_003.0, 1_000_004.0]


def test_a_full_ring_still_replaces_within_the_second() -> None:
    clock = Clock()
    temps = Temperatures(clock)
    for step in range(CAPACITY + 3):
        clock.now = 1_000_000.0 + step
        status = {"extruder": heater(float(step))}
        temps.feed("p", status, status)
    clock.now += 0.5
    status = {"extruder": heater(-1.0)}
    temps.feed("p", status, status)
    ring = temps._printers["p"]["extruder"]
    assert ring.count == CAPACITY
    assert ring.at(ring.last) == (clock.now, -1.0, 0.0)


def test_a_ring_holds_what_it_was_fed_in_tenths_and_grows_only_to_capacity() -> None:
    clock = Clock(1_700_000_000.123)
    temps = Temperatures(clock)
    status = {"extruder": heater(215.04, 215)}
    temps.feed("p", status, status)
    ring = temps._printers["p"]["extruder"]
    # A printer that reported once holds one sample, not the half hour's ring.
    assert len(ring.times) == len(ring.temperature) == len(ring.target) == 1
    clock.now += 1.26
    status = {"extruder": heater(1e6, -1e6)}  # a broken thermistor: clamped, not an error
    temps.feed("p", status, status)
    assert ring.at(0) == (1_700_000_000.123, 215.0, 215.0)
    assert ring.at(1) == (pytest.approx(1_700_000_001.423), 3276.7, -3276.7)
    for step in range(2, CAPACITY * 2):
        clock.now = 1_700_000_000.123 + step
        temps.feed("p", status, status)
    assert len(ring.times) == len(ring.temperature) == len(ring.target) == CAPACITY
    assert ring.times.itemsize + ring.temperature.itemsize + ring.target.itemsize == 8
