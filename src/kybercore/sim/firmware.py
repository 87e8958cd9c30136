"""The virtual MCU's firmware: link layer (sequence numbers, ack/nak), command dispatch,
shutdown and reset. No I/O: bytes come in through `receive`, go out through `send`, and time
comes from the `clock` callable, so tests can drive it with a fake clock.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, TypeVar

from kybercore.sim import board, thermal
from kybercore.sim.mcu_protocol import (
    ADC_MAX,
    CLOCK_FREQ,
    MESSAGE_SEQ_MASK,
    MOVE_COUNT,
    STATS_SUMSQ_BASE,
    BlockDecoder,
    MessageFormat,
    ProtocolError,
    Value,
    build_dictionary,
    decode_vlq,
    encode_block,
)
from kybercore.sim.peripherals import (
    AnalogIn,
    DigitalOut,
    Endstop,
    Scheduler,
    Stepper,
    Trsync,
)

log = logging.getLogger(__name__)

# Endstops close this long after homing starts: the axis has "travelled" far enough to look
# like a homing move, G28 stays quick, and the hit comes before the trsync's first expiry
# (0.25 s after the start), so homing never depends on the host extending that in time.
HOMING_TRIGGER_SECONDS: Final = 0.2
STATS_PERIOD_SECONDS: Final = 5.0
# Commands the real firmware still accepts after a shutdown; anything else is answered with
# `is_shutdown`.
_ALLOWED_IN_SHUTDOWN: Final = frozenset(
    {
        "identify",
        "get_uptime",
        "get_clock",
        "get_config",
        "emergency_stop",
        "clear_shutdown",
        "reset",
        "stepper_get_position",
        "endstop_query_state",
        "trsync_trigger",
    }
)

_T = TypeVar("_T")


@dataclass(frozen=True)
class ThermalSettings:
    """Speed-up factors for the heaters (1.0 is realistic) and the room temperature."""

    heat_factor: float = 1.0
    cool_factor: float = 1.0
    ambient: float = 25.0


class _Abort(Exception):
    """Stop dispatching the current block (the MCU just shut down)."""


class VirtualFirmware:
    """One MCU. Call `receive` with host bytes and `run_timers` when `next_wake` comes."""

    def __init__(
        self,
        clock: Callable[[], int],
        send: Callable[[bytes], None],
        settings: ThermalSettings | None = None,
        on_reset: Callable[[], None] = lambda: None,
    ) -> None:
        settings = settings or ThermalSettings()
        self._clock = clock
        self._send = send
        self._on_reset = on_reset
        self._dictionary = build_dictionary()
        self._decoder = BlockDecoder()
        self._handlers: dict[str, Callable[[dict[str, int]], None]] = {
            fmt.name: getattr(self, "_cmd_" + fmt.name)
            for fmt in self._dictionary.commands.values()
        }
        now = self._seconds(clock())
        # Heaters belong to the board, not the firmware: they keep their heat across resets.
        self.heaters = {
            board.HOTEND_HEATER: thermal.HeaterModel(
                thermal.HOTEND.scaled(settings.heat_factor, settings.cool_factor),
                settings.ambient,
                now,
            ),
            board.BED_HEATER: thermal.HeaterModel(
                thermal.BED.scaled(settings.heat_factor, settings.cool_factor),
                settings.ambient,
                now,
            ),
        }
        self._sensors = {
            board.HOTEND_SENSOR: board.HOTEND_HEATER,
            board.BED_SENSOR: board.BED_HEATER,
        }
        self._ambient = settings.ambient
        self._stats_count = self._stats_sum = self._stats_sumsq = 0
        self._stats_start = clock()
        self._boot()

    def _boot(self) -> None:
        """Power-on state (also after `reset`)."""
        self._next_seq = 1
        self._decoder.reset()
        self._scheduler = Scheduler()
        self._oids: dict[int, object] = {}
        self._oid_count = 0
        self._config_crc = 0
        self._is_config = False
        self._shutdown_reason: str | None = None
        self._reset_requested = False
        now = self._clock()
        for heater in self.heaters.values():
            heater.set_duty(0.0, self._seconds(now))

    # ----- link layer -------------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        """Process bytes from the host: ack good blocks, nak unexpected or corrupt ones."""
        start = self._clock()
        for block in self._decoder.feed(data):
            if block is None or block.seq != self._next_seq:
                # A nak is an empty block carrying the sequence number we still expect.
                self._send(encode_block(self._next_seq, b""))
                continue
            self._next_seq = (block.seq + 1) & MESSAGE_SEQ_MASK
            self._dispatch(block.payload)
            if self._reset_requested:
                self._reset()
                return
            # Ack every block, even one already answered: Klippy only wakes a waiting
            # sender on the ack.
            self._send(encode_block(self._next_seq, b""))
        self._account(start)

    def next_wake(self) -> int:
        """Clock at which `run_timers` has work (at most one stats period away)."""
        stats_due = self._stats_start + int(STATS_PERIOD_SECONDS * CLOCK_FREQ)
        timer = self._scheduler.next_clock()
        return stats_due if timer is None else min(timer, stats_due)

    def run_timers(self) -> None:
        """Run everything due by now."""
        start = self._clock()
        with contextlib.suppress(_Abort):
            self._scheduler.run_due(start)
        self._account(start)
        if start - self._stats_start >= STATS_PERIOD_SECONDS * CLOCK_FREQ:
            self._respond(
                "stats",
                self._stats_count,
                self._stats_sum & 0xFFFFFFFF,
                min(self._stats_sumsq, 0xFFFFFFFF),
            )
            self._stats_count = self._stats_sum = self._stats_sumsq = 0
            self._stats_start = start

    def _account(self, start: int) -> None:
        busy = self._clock() - start
        self._stats_count += 1
        self._stats_sum += busy
        self._stats_sumsq += busy * busy // STATS_SUMSQ_BASE

    def _respond(self, name: str, *values: Value) -> None:
        self._send(encode_block(self._next_seq, self._dictionary.response(name, *values)))

    def _dispatch(self, payload: bytes) -> None:
        pos = 0
        try:
            while pos < len(payload):
                msgid, pos = decode_vlq(payload, pos)
                fmt = self._dictionary.commands.get(msgid)
                if fmt is None:
                    self._shutdown("Invalid command")
                    return
                params, pos = fmt.decode(payload, pos)
                self._call(fmt, params)
                if self._reset_requested:
                    return
        except ProtocolError as exc:
            log.warning("Malformed command block: %s", exc)
            self._shutdown("Invalid command")
        except _Abort:
            pass

    def _call(self, fmt: MessageFormat, params: dict[str, Value]) -> None:
        if self._shutdown_reason is not None and fmt.name not in _ALLOWED_IN_SHUTDOWN:
            self._respond("is_shutdown", self._dictionary.static_strings[self._shutdown_reason])
            return
        ints = {name: value for name, value in params.items() if isinstance(value, int)}
        self._handlers[fmt.name](ints)

    # ----- helpers ----------------------------------------------------------------------

    def _extend(self, clock32: int) -> int:
        """The 64-bit clock nearest to now whose low 32 bits are `clock32`."""
        now = self._clock()
        clock = (now & ~0xFFFFFFFF) | (clock32 & 0xFFFFFFFF)
        if clock < now - 0x80000000:
            clock += 1 << 32
        elif clock > now + 0x80000000:
            clock -= 1 << 32
        return clock

    @staticmethod
    def _seconds(clock: int) -> float:
        return clock / CLOCK_FREQ

    def _lookup(self, oid: int, kind: type[_T]) -> _T:
        obj = self._oids.get(oid)
        if not isinstance(obj, kind):
            self._shutdown("Invalid oid type")
            raise _Abort
        return obj

    def _assign(self, oid: int, obj: object) -> None:
        if oid >= self._oid_count or oid in self._oids:
            self._shutdown("Can't assign oid")
            raise _Abort
        self._oids[oid] = obj

    def _shutdown(self, reason: str) -> None:
        """Enter shutdown: outputs to their defaults, timers dropped, host told why."""
        if self._shutdown_reason is not None:
            return
        log.warning("MCU shutdown: %s", reason)
        self._shutdown_reason = reason
        now = self._clock()
        for obj in self._oids.values():
            if isinstance(obj, DigitalOut):
                obj.apply(obj.default_duty, now)
            elif isinstance(obj, Stepper):
                obj.stop(now)
            elif isinstance(obj, Endstop):
                obj.stop()
        self._scheduler.clear()
        self._respond("shutdown", now & 0xFFFFFFFF, self._dictionary.static_strings[reason])

    def _reset(self) -> None:
        log.info("MCU reset requested by the host")
        self._boot()
        self._on_reset()

    # ----- basic commands ---------------------------------------------------------------

    def _cmd_identify(self, p: dict[str, int]) -> None:
        offset = p["offset"]
        chunk = self._dictionary.compressed[offset : offset + min(p["count"], 40)]
        self._respond("identify_response", offset, chunk)

    def _cmd_get_uptime(self, _p: dict[str, int]) -> None:
        now = self._clock()
        self._respond("uptime", now >> 32, now & 0xFFFFFFFF)

    def _cmd_get_clock(self, _p: dict[str, int]) -> None:
        self._respond("clock", self._clock() & 0xFFFFFFFF)

    def _cmd_get_config(self, _p: dict[str, int]) -> None:
        self._respond(
            "config",
            int(self._is_config),
            self._config_crc,
            int(self._shutdown_reason is not None),
            MOVE_COUNT,
        )

    def _cmd_allocate_oids(self, p: dict[str, int]) -> None:
        self._oids.clear()
        self._oid_count = p["count"]

    def _cmd_finalize_config(self, p: dict[str, int]) -> None:
        self._config_crc = p["crc"]
        self._is_config = True

    def _cmd_emergency_stop(self, _p: dict[str, int]) -> None:
        self._shutdown("Command request")

    def _cmd_reset(self, _p: dict[str, int]) -> None:
        self._reset_requested = True

    def _cmd_clear_shutdown(self, _p: dict[str, int]) -> None:
        if self._shutdown_reason is None:
            self._shutdown("Shutdown cleared when not shutdown")
            return
        self._shutdown_reason = None

    # ----- steppers ---------------------------------------------------------------------

    def _cmd_config_stepper(self, p: dict[str, int]) -> None:
        self._assign(p["oid"], Stepper())

    def _cmd_queue_step(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], Stepper).queue_step(
            p["interval"], p["count"], p["add"], self._clock()
        )

    def _cmd_set_next_step_dir(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], Stepper).set_next_dir(p["dir"])

    def _cmd_reset_step_clock(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], Stepper).reset_clock(self._extend(p["clock"]))

    def _cmd_stepper_get_position(self, p: dict[str, int]) -> None:
        position = self._lookup(p["oid"], Stepper).position(self._clock())
        self._respond("stepper_position", p["oid"], position)

    def _cmd_stepper_stop_on_trigger(self, p: dict[str, int]) -> None:
        stepper = self._lookup(p["oid"], Stepper)
        self._lookup(p["trsync_oid"], Trsync).add_stop(stepper.stop)

    # ----- homing -----------------------------------------------------------------------

    def _cmd_config_trsync(self, p: dict[str, int]) -> None:
        self._assign(p["oid"], Trsync(p["oid"], self._scheduler, self._report_trsync))

    def _report_trsync(self, trsync: Trsync, clock: int) -> None:
        self._respond(
            "trsync_state",
            trsync.oid,
            int(trsync.can_trigger),
            trsync.trigger_reason,
            clock & 0xFFFFFFFF,
        )

    def _cmd_trsync_start(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], Trsync).start(
            self._extend(p["report_clock"]), p["report_ticks"], p["expire_reason"]
        )

    def _cmd_trsync_set_timeout(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], Trsync).set_timeout(self._extend(p["clock"]))

    def _cmd_trsync_trigger(self, p: dict[str, int]) -> None:
        trsync = self._lookup(p["oid"], Trsync)
        now = self._clock()
        trsync.trigger(p["reason"], now)
        # Klippy uses this command as a query: always answer, triggered or not.
        self._report_trsync(trsync, now)

    def _cmd_config_endstop(self, p: dict[str, int]) -> None:
        delay = int(HOMING_TRIGGER_SECONDS * CLOCK_FREQ)
        self._assign(p["oid"], Endstop(self._scheduler, delay))

    def _cmd_endstop_home(self, p: dict[str, int]) -> None:
        endstop = self._lookup(p["oid"], Endstop)
        trsync = self._lookup(p["trsync_oid"], Trsync) if p["sample_count"] else None
        endstop.home(
            self._extend(p["clock"]),
            p["sample_count"],
            p["rest_ticks"],
            trsync,
            p["trigger_reason"],
        )

    def _cmd_endstop_query_state(self, p: dict[str, int]) -> None:
        endstop = self._lookup(p["oid"], Endstop)
        # The switch reads open except at the instant it triggers a homing move.
        self._respond(
            "endstop_state", p["oid"], int(endstop.homing), endstop.next_clock & 0xFFFFFFFF, 0
        )

    # ----- outputs ----------------------------------------------------------------------

    def _cmd_config_digital_out(self, p: dict[str, int]) -> None:
        heater = self.heaters.get(board.pin_name(p["pin"]))

        def on_duty(duty: float, clock: int) -> None:
            if heater is not None:
                heater.set_duty(duty, self._seconds(clock))

        def on_overdue() -> None:
            self._shutdown("Missed scheduling of next digital out event")

        out = DigitalOut(
            self._scheduler, p["value"], p["default_value"], p["max_duration"], on_duty, on_overdue
        )
        self._assign(p["oid"], out)
        out.apply(out.duty, self._clock())

    def _cmd_set_digital_out_pwm_cycle(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], DigitalOut).cycle_ticks = p["cycle_ticks"]

    def _cmd_queue_digital_out(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], DigitalOut).queue(self._extend(p["clock"]), p["on_ticks"])

    def _cmd_update_digital_out(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], DigitalOut).apply(float(bool(p["value"])), self._clock())

    def _cmd_set_digital_out(self, p: dict[str, int]) -> None:
        heater = self.heaters.get(board.pin_name(p["pin"]))
        if heater is not None:
            heater.set_duty(float(bool(p["value"])), self._seconds(self._clock()))

    # ----- analog inputs ----------------------------------------------------------------

    def _cmd_config_analog_in(self, p: dict[str, int]) -> None:
        heater = self.heaters.get(self._sensors.get(board.pin_name(p["pin"]), ""))

        def read(clock: int, sample_count: int) -> int:
            # A sensor with no heater behind it reads the room.
            temp = self._ambient if heater is None else heater.temperature(self._seconds(clock))
            return thermal.adc_sum(temp, ADC_MAX, sample_count)

        def report(oid: int, next_clock: int, value: int) -> None:
            self._respond("analog_in_state", oid, next_clock & 0xFFFFFFFF, value)

        def out_of_range() -> None:
            self._shutdown("ADC out of range")

        self._assign(p["oid"], AnalogIn(p["oid"], self._scheduler, read, report, out_of_range))

    def _cmd_query_analog_in(self, p: dict[str, int]) -> None:
        self._lookup(p["oid"], AnalogIn).query(
            self._extend(p["clock"]),
            p["sample_count"],
            p["rest_ticks"],
            p["min_value"],
            p["max_value"],
            p["range_check_count"],
        )
