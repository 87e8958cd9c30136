"""The virtual MCU's timer queue and its objects: steppers, trsyncs, endstops, outputs, ADCs.

Everything runs on the MCU clock (integer ticks, extended to 64 bits). Nothing here does I/O:
objects report through callbacks the firmware gives them.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

TimerCallback = Callable[[int], None]


class Timer:
    """A scheduled callback; `cancel` makes it a no-op."""

    __slots__ = ("active", "callback", "clock")

    def __init__(self, clock: int, callback: TimerCallback) -> None:
        self.clock = clock
        self.callback = callback
        self.active = True

    def cancel(self) -> None:
        """Do not run this timer."""
        self.active = False


class Scheduler:
    """Timers ordered by clock; ties run in scheduling order."""

    def __init__(self) -> None:
        self._heap: list[tuple[int, int, Timer]] = []
        self._order = itertools.count()

    def schedule(self, clock: int, callback: TimerCallback) -> Timer:
        """Run `callback(clock)` once the MCU clock reaches `clock`."""
        timer = Timer(clock, callback)
        heapq.heappush(self._heap, (clock, next(self._order), timer))
        return timer

    def next_clock(self) -> int | None:
        """Clock of the earliest pending timer."""
        while self._heap and not self._heap[0][2].active:
            heapq.heappop(self._heap)
        return self._heap[0][0] if self._heap else None

    def run_due(self, now: int) -> None:
        """Run every timer whose clock is <= `now`, in clock order."""
        while self._heap and self._heap[0][0] <= now:
            _, _, timer = heapq.heappop(self._heap)
            if timer.active:
                timer.active = False
                timer.callback(timer.clock)

    def clear(self) -> None:
        """Drop every timer (MCU shutdown or reset)."""
        for _, _, timer in self._heap:
            timer.active = False
        self._heap.clear()


@dataclass(frozen=True)
class _Move:
    """One queue_step: `count` steps, the k-th at ``base + k*interval + add*k*(k-1)/2``."""

    base: int
    interval: int
    count: int
    add: int
    sign: int

    def step_clock(self, k: int) -> int:
        return self.base + k * self.interval + self.add * k * (k - 1) // 2

    @property
    def end(self) -> int:
        return self.step_clock(self.count)

    def steps_by(self, clock: int) -> int:
        """How many of this move's steps happen at or before `clock`."""
        if clock >= self.end:
            return self.count
        elapsed = clock - self.base
        if elapsed < self.interval:
            return 0
        if self.add == 0:
            k = elapsed // self.interval
        else:
            a, b = 0.5 * self.add, self.interval - 0.5 * self.add
            k = int((math.sqrt(max(0.0, b * b + 4 * a * elapsed)) - b) / (2 * a))
        # The float estimate can be one off either way; settle it with exact integers.
        k = max(0, min(self.count, k))
        while k < self.count and self.step_clock(k + 1) <= clock:
            k += 1
        while k > 0 and self.step_clock(k) > clock:
            k -= 1
        return k


class Stepper:
    """Step position bookkeeping. Steps are not simulated one by one: they are counted lazily
    from the queued moves, so a trsync can cut a move off at any clock exactly."""

    _FOLD_AFTER = 64

    def __init__(self) -> None:
        self._position = 0
        self._next_dir = 0
        self._last_clock = 0
        self._moves: deque[_Move] = deque()
        self._need_reset = False

    def queue_step(self, interval: int, count: int, add: int, now: int) -> None:
        """Append a move; ignored after a trsync stop until `reset_clock`, as the firmware does
        (otherwise steps the host already sent would land after the endstop hit)."""
        if self._need_reset or count == 0:
            return
        move = _Move(self._last_clock, interval, count, add, 1 if self._next_dir else -1)
        self._moves.append(move)
        self._last_clock = move.end
        if len(self._moves) > self._FOLD_AFTER:
            self._fold(now)

    def set_next_dir(self, direction: int) -> None:
        """Direction of the moves queued from now on (1 counts up)."""
        self._next_dir = direction

    def reset_clock(self, clock: int) -> None:
        """The next move's steps are timed from `clock`."""
        self._fold(clock)
        self._last_clock = clock
        self._need_reset = False

    def position(self, clock: int) -> int:
        """Step position at `clock` (steps queued for later are not counted)."""
        return self._position + sum(m.sign * m.steps_by(clock) for m in self._moves)

    def stop(self, clock: int) -> None:
        """Halt at `clock`: steps after it never happen."""
        self._position = self.position(clock)
        self._moves.clear()
        self._need_reset = True

    def _fold(self, clock: int) -> None:
        while self._moves and self._moves[0].end <= clock:
            move = self._moves.popleft()
            self._position += move.sign * move.count


ReportTrsync = Callable[["Trsync", int], None]


class Trsync:
    """Trigger synchronisation: the first trigger (endstop, timeout or host) stops its steppers."""

    def __init__(self, oid: int, scheduler: Scheduler, report: ReportTrsync) -> None:
        self.oid = oid
        self.can_trigger = False
        self.trigger_reason = 0
        self._scheduler = scheduler
        self._report = report
        self._expire_reason = 0
        self._report_ticks = 0
        self._report_timer: Timer | None = None
        self._timeout_timer: Timer | None = None
        self._stops: list[Callable[[int], None]] = []

    def start(self, report_clock: int, report_ticks: int, expire_reason: int) -> None:
        """Arm; report the state every `report_ticks` from `report_clock` while armed."""
        self._cancel_timers()
        self._stops.clear()
        self.can_trigger = True
        self.trigger_reason = 0
        self._expire_reason = expire_reason
        self._report_ticks = report_ticks
        if report_ticks:
            self._report_timer = self._scheduler.schedule(report_clock, self._periodic_report)

    def set_timeout(self, clock: int) -> None:
        """Trigger with the expire reason at `clock` unless something triggers first."""
        if self._timeout_timer is not None:
            self._timeout_timer.cancel()
        self._timeout_timer = self._scheduler.schedule(
            clock, lambda at: self.trigger(self._expire_reason, at)
        )

    def add_stop(self, stop: Callable[[int], None]) -> None:
        """Call `stop(trigger_clock)` on the next trigger."""
        self._stops.append(stop)

    def trigger(self, reason: int, clock: int) -> None:
        """Trigger at `clock` if still armed, stop the steppers and report at once."""
        if not self.can_trigger:
            return
        self.can_trigger = False
        self.trigger_reason = reason
        self._cancel_timers()
        for stop in self._stops:
            stop(clock)
        self._stops.clear()
        self._report(self, clock)

    def _periodic_report(self, clock: int) -> None:
        self._report(self, clock)
        if self.can_trigger:
            self._report_timer = self._scheduler.schedule(
                clock + self._report_ticks, self._periodic_report
            )

    def _cancel_timers(self) -> None:
        for timer in (self._report_timer, self._timeout_timer):
            if timer is not None:
                timer.cancel()
        self._report_timer = self._timeout_timer = None


class Endstop:
    """A switch that closes a fixed time after homing starts.

    The virtual axis has no physical extent; what matters to Klippy is that the trigger clock
    lies on the sampling grid and that `next_clock` (trigger + rest_ticks) says when.
    """

    def __init__(self, scheduler: Scheduler, trigger_delay: int) -> None:
        self.homing = False
        self.next_clock = 0
        self._scheduler = scheduler
        self._trigger_delay = trigger_delay
        self._timer: Timer | None = None

    def home(
        self, clock: int, sample_count: int, rest_ticks: int, trsync: Trsync | None, reason: int
    ) -> None:
        """Start homing (or stop it when `sample_count` is 0)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self.homing = bool(sample_count) and trsync is not None
        if not self.homing or trsync is None:
            return
        rest = max(1, rest_ticks)
        trigger_clock = clock + -(-self._trigger_delay // rest) * rest

        def hit(at: int) -> None:
            self.homing = False
            self.next_clock = at + rest
            trsync.trigger(reason, at)

        self._timer = self._scheduler.schedule(trigger_clock, hit)

    def stop(self) -> None:
        """Forget any homing in progress (shutdown)."""
        self.home(0, 0, 0, None, 0)


class DigitalOut:
    """An output pin, optionally software-PWM. Reports duty changes to `on_duty`; if
    `max_duration` passes without an update while off its default, calls `on_overdue`."""

    def __init__(
        self,
        scheduler: Scheduler,
        value: int,
        default_value: int,
        max_duration: int,
        on_duty: Callable[[float, int], None],
        on_overdue: Callable[[], None],
    ) -> None:
        self.cycle_ticks = 0
        self.default_duty = float(bool(default_value))
        self.duty = float(bool(value))
        self._scheduler = scheduler
        self._max_duration = max_duration
        self._on_duty = on_duty
        self._on_overdue = on_overdue
        self._generation = 0

    def queue(self, clock: int, on_ticks: int) -> None:
        """Set the pin at `clock`: on-time per cycle in soft-PWM mode, else on (non-zero)/off."""
        duty = float(bool(on_ticks))
        if self.cycle_ticks:
            duty = min(1.0, on_ticks / self.cycle_ticks)
        self._scheduler.schedule(clock, lambda at: self.apply(duty, at))

    def apply(self, duty: float, clock: int) -> None:
        """Switch to `duty` now (clock `clock`) and re-arm the max_duration watchdog."""
        self.duty = duty
        self._generation += 1
        self._on_duty(duty, clock)
        if self._max_duration and duty != self.default_duty:
            generation = self._generation
            # One tick late so an update scheduled exactly at the deadline still wins.
            self._scheduler.schedule(
                clock + self._max_duration + 1, lambda _at: self._check_overdue(generation)
            )

    def _check_overdue(self, generation: int) -> None:
        if generation == self._generation and self.duty != self.default_duty:
            self._on_overdue()


class AnalogIn:
    """An ADC channel sampled periodically; out-of-range readings call `on_out_of_range`."""

    def __init__(
        self,
        oid: int,
        scheduler: Scheduler,
        read: Callable[[int, int], int],
        report: Callable[[int, int, int], None],
        on_out_of_range: Callable[[], None],
    ) -> None:
        self.oid = oid
        self._scheduler = scheduler
        self._read = read
        self._report = report
        self._on_out_of_range = on_out_of_range
        self._sample_count = 0
        self._rest_ticks = 0
        self._min = 0
        self._max = 0
        self._range_check_count = 0
        self._invalid = 0
        self._timer: Timer | None = None

    def query(
        self,
        clock: int,
        sample_count: int,
        rest_ticks: int,
        min_value: int,
        max_value: int,
        range_check_count: int,
    ) -> None:
        """Sample every `rest_ticks` from `clock` (sample_count 0 stops)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._sample_count = sample_count
        self._rest_ticks = rest_ticks
        self._min, self._max = min_value, max_value
        self._range_check_count = range_check_count
        self._invalid = 0
        if sample_count:
            self._timer = self._scheduler.schedule(clock, self._sample)

    def _sample(self, clock: int) -> None:
        value = self._read(clock, self._sample_count)
        next_clock = clock + self._rest_ticks
        self._report(self.oid, next_clock, value)
        if self._min <= value <= self._max:
            self._invalid = 0
        else:
            self._invalid += 1
            if self._invalid >= self._range_check_count:
                self._on_out_of_range()
                return
        self._timer = self._scheduler.schedule(next_clock, self._sample)
