"""The heaters' ring buffer: one sample a second, held values, gaps, a bounded window."""

from __future__ import annotations

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
    assert len(temps._printers["p"]["extruder"].temperature) == CAPACITY


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
    series = temps.series("p")["extruder"]
    assert series["temperature"][-1] == -1.0
    assert series["temperature"][-2] == float(CAPACITY + 1)
    assert series["t"][-1] == 1_000_000.0 + CAPACITY + 2


def test_values_in_tenths_clamped_and_nothing_held_for_a_printer_never_heard() -> None:
    clock = Clock(1_700_000_000.5)
    temps = Temperatures(clock)
    temps.gap("p")  # offline from the start
    assert temps._printers == {}
    status = {"extruder": heater(215.04, 215)}
    temps.feed("p", status, status)
    clock.now += 1
    status = {"extruder": heater(1e6, -1e6)}  # a broken thermistor: clamped, not an error
    temps.feed("p", status, status)
    series = temps.series("p")["extruder"]
    assert series["t"] == [1_700_000_000.0, 1_700_000_001.0]
    assert series["temperature"] == [215.0, 3276.7]
    assert series["target"] == [215.0, -3276.6]
    ring = temps._printers["p"]["extruder"]
    assert ring.temperature.itemsize + ring.target.itemsize == 4  # bytes a second


def test_a_silent_stretch_shows_no_samples_from_before_it_as_recent() -> None:
    # Slots are seconds modulo the capacity: the ones skipped over must not keep old values.
    clock = Clock()
    temps = Temperatures(clock)
    for step in range(CAPACITY):
        clock.now = 1_000_000.0 + step
        status = {"extruder": heater(float(step % 100))}
        temps.feed("p", status, status)
    for silence in (600, CAPACITY - 1, 3 * CAPACITY):
        clock.now += silence
        status = {"extruder": heater(42.0)}
        temps.feed("p", status, status)
        series = temps.series("p")["extruder"]
        assert all(t >= clock.now - WINDOW_SECONDS for t in series["t"])
        assert series["t"][-1] == clock.now
        recent = [t for t in series["t"] if t > clock.now - silence]
        assert recent == [clock.now]


def test_a_clock_set_back_keeps_what_it_can() -> None:
    clock = Clock()
    temps = Temperatures(clock)
    for step in (0, 1, 2):
        clock.now = 1_000_000.0 + step
        status = {"extruder": heater(20.0 + step)}
        temps.feed("p", status, status)
    clock.now = 1_000_001.0  # set back a second: that second's value is replaced
    status = {"extruder": heater(30.0)}
    temps.feed("p", status, status)
    clock.now = 1_000_000.0 - 2 * CAPACITY  # further back than the window: ignored
    temps.feed("p", status, status)
    clock.now = 1_000_002.0
    assert temps.series("p")["extruder"]["temperature"] == [20.0, 30.0, 22.0]
