"""Fast tests without processes: wire protocol, thermal model, firmware logic, printer.cfg.

Where Klippy's own `msgproto.py` is installed (the Klippy venv), it is loaded straight from its
file and used as the reference host; those tests skip when it is missing.
"""

from __future__ import annotations

import configparser
import importlib.util
import math
import os
import zlib
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kybercore.sim import board, thermal
from kybercore.sim.firmware import ThermalSettings, VirtualFirmware
from kybercore.sim.mcu_protocol import (
    COMMANDS,
    MESSAGE_SYNC,
    BlockDecoder,
    MessageFormat,
    build_dictionary,
    crc16_ccitt,
    decode_vlq,
    encode_block,
    encode_vlq,
)
from kybercore.sim.peripherals import Stepper, _Move
from kybercore.sim.printer_cfg import PrinterSpec, render_printer_cfg

KLIPPY_PYTHON = Path(
    os.environ.get(
        "KYBERCORE_KLIPPY_PYTHON", "/root/.local/share/kybercore/venvs/klippy/bin/python"
    )
)


@pytest.fixture(scope="module")
def msgproto() -> ModuleType:
    """Klippy's msgproto module, loaded from the Klippy venv."""
    venv = KLIPPY_PYTHON.parent.parent
    found = sorted(venv.glob("lib/python3*/site-packages/klippy/msgproto.py"))
    if not found:
        pytest.skip(f"Klippy's msgproto.py not found next to {KLIPPY_PYTHON}")
    spec = importlib.util.spec_from_file_location("klippy_msgproto", found[0])
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ----- framing, CRC, VLQ ----------------------------------------------------------------------


def test_crc16_check_value() -> None:
    # The published check value of CRC-16/MCRF4XX, the variant Klipper uses.
    assert crc16_ccitt(b"123456789") == 0x6F91


@given(st.binary(max_size=80))
def test_crc16_matches_klippy(msgproto: ModuleType, data: bytes) -> None:
    crc = crc16_ccitt(data)
    assert msgproto.crc16_ccitt(data) == [crc >> 8, crc & 0xFF]


@given(st.integers(min_value=-(2**31), max_value=2**32 - 1))
def test_vlq_roundtrip_and_klippy_agree(msgproto: ModuleType, value: int) -> None:
    encoded = encode_vlq(value)
    decoded, end = decode_vlq(encoded, 0)
    assert end == len(encoded)
    assert decoded & 0xFFFFFFFF == value & 0xFFFFFFFF
    # Klippy decodes ours and we decode Klippy's.
    klippy_value, _ = msgproto.PT_uint32().parse(encoded, 0)
    assert klippy_value == value & 0xFFFFFFFF
    out: list[int] = []
    msgproto.PT_int32().encode(out, value if value < 2**31 else value - 2**32)
    assert decode_vlq(bytes(out), 0)[0] & 0xFFFFFFFF == value & 0xFFFFFFFF


def test_small_ids_are_one_byte() -> None:
    assert all(len(encode_vlq(i)) == 1 for i in range(96))


def test_block_passes_klippy_check_and_parse(msgproto: ModuleType) -> None:
    fmt = MessageFormat(0, "identify_response offset=%u data=%.*s")
    block = encode_block(3, fmt.encode(1234, b"hello"))
    parser = msgproto.MessageParser()
    assert parser.check_packet(bytearray(block)) == len(block)
    params = parser.parse(bytearray(block))
    assert params["offset"] == 1234
    assert params["data"] == b"hello"


def test_decoder_reassembles_split_input_and_skips_sync_bytes() -> None:
    blocks = [encode_block(seq, bytes([seq, 1, 2])) for seq in range(5)]
    stream = bytes([MESSAGE_SYNC]) + b"".join(blocks)
    decoder = BlockDecoder()
    got = []
    for i in range(len(stream)):  # one byte at a time
        got += decoder.feed(stream[i : i + 1])
    assert [(b.seq, b.payload) for b in got if b] == [(s, bytes([s, 1, 2])) for s in range(5)]


def test_decoder_reports_corruption_then_recovers() -> None:
    good = encode_block(1, b"\x05")
    bad = bytearray(encode_block(2, b"\x06"))
    bad[2] ^= 0xFF  # payload changed: CRC no longer matches
    out = BlockDecoder().feed(bytes(bad) + good)
    assert out[0] is None
    assert out[-1] is not None
    assert (out[-1].seq, out[-1].payload) == (1, b"\x05")


def test_dictionary_loads_in_klippy(msgproto: ModuleType) -> None:
    dictionary = build_dictionary()
    parser = msgproto.MessageParser()
    parser.process_identify(dictionary.compressed)
    # Exact formats Klippy's mcu.py/stepper.py look up; a mismatch raises.
    for fmt in COMMANDS:
        parser.lookup_command(fmt)
    assert parser.get_constant_float("CLOCK_FREQ") == 1_000_000
    enums = parser.get_enumerations()
    assert enums["pin"]["PC15"] == 47
    assert enums["static_string_id"]["ADC out of range"] >= 0
    cmd = parser.create_command("config_endstop oid=3 pin=PB0 pull_up=1")
    assert dictionary.commands[cmd[0]].decode(bytes(cmd), 1)[0] == {
        "oid": 3,
        "pin": 16,
        "pull_up": 1,
    }


def test_pin_names() -> None:
    assert board.pin_name(0) == "PA0"
    assert board.pin_name(47) == "PC15"
    with pytest.raises(ValueError, match="no pin"):
        board.pin_name(48)


# ----- thermal model --------------------------------------------------------------------------


def _time_to(profile: thermal.ThermalProfile, target: float, ambient: float = 25.0) -> float:
    model = thermal.HeaterModel(profile, ambient, 0.0)
    model.set_duty(1.0, 0.0)
    t = 0.0
    while model.temperature(t) < target:
        t += 0.05
        assert t < 600, "never reached the target"
    return t


def test_default_profiles_heat_realistically() -> None:
    assert 25 <= _time_to(thermal.HOTEND, 200) <= 35
    assert 20 <= _time_to(thermal.BED, 60) <= 35


def test_speed_factor_scales_time() -> None:
    slow = _time_to(thermal.HOTEND, 200)
    fast = _time_to(thermal.HOTEND.scaled(8, 8), 200)
    assert fast == pytest.approx(slow / 8, abs=0.1)


def test_heater_settles_and_cools() -> None:
    profile = thermal.ThermalProfile(heat_rate=10, loss_rate=0.1)
    model = thermal.HeaterModel(profile, 20.0, 0.0)
    model.set_duty(0.5, 0.0)
    assert model.temperature(500.0) == pytest.approx(20 + 10 * 0.5 / 0.1)
    model.set_duty(0.0, 500.0)
    assert model.temperature(510.0) == pytest.approx(20 + 50 * math.exp(-1.0))
    assert model.temperature(400.0) == model.temperature(510.0)  # never runs backwards


@given(st.floats(min_value=-20, max_value=350))
def test_thermistor_inverts_like_klippy(temp: float) -> None:
    # Klippy's beta model, solved for temperature from the ADC fraction.
    fraction = thermal.thermistor_fraction(temp)
    resistance = thermal.PULLUP_OHMS * fraction / (1 - fraction)
    inv_t = 1 / (25 + thermal.KELVIN) + math.log(resistance / 100_000) / 3950
    assert 1 / inv_t - thermal.KELVIN == pytest.approx(temp, abs=1e-6)


def test_adc_falls_as_temperature_rises() -> None:
    assert thermal.adc_sum(25, 4095, 8) > thermal.adc_sum(200, 4095, 8) > 0


# ----- step timing ----------------------------------------------------------------------------


@given(
    interval=st.integers(1, 5000),
    count=st.integers(1, 300),
    add=st.integers(-20, 20),
    probe=st.integers(0, 2_000_000),
)
def test_move_step_count_matches_brute_force(
    interval: int, count: int, add: int, probe: int
) -> None:
    if interval + (count - 1) * add <= 0:
        return  # the host never sends intervals that go non-positive
    move = _Move(base=1000, interval=interval, count=count, add=add, sign=1)
    clock, expected = 1000, 0
    step = interval
    for _ in range(count):
        clock += step
        if clock <= 1000 + probe:
            expected += 1
        step += add
    assert move.steps_by(1000 + probe) == expected


def test_stepper_stop_drops_later_steps_until_reset() -> None:
    stepper = Stepper()
    stepper.set_next_dir(1)
    stepper.reset_clock(0)
    stepper.queue_step(interval=100, count=50, add=0, now=0)  # steps at 100..5000
    stepper.stop(1050)
    assert stepper.position(10_000) == 10
    stepper.queue_step(interval=100, count=5, add=0, now=2000)  # ignored: needs a reset
    assert stepper.position(10_000) == 10
    stepper.set_next_dir(0)
    stepper.reset_clock(20_000)
    stepper.queue_step(interval=10, count=4, add=0, now=20_000)
    assert stepper.position(20_035) == 7
    assert stepper.position(30_000) == 6


# ----- firmware, driven by a fake clock -------------------------------------------------------


class FakeHost:
    """Speaks to a VirtualFirmware the way Klippy does, on a clock the test controls."""

    def __init__(self, settings: ThermalSettings | None = None) -> None:
        self.now = 0
        self.sent: list[bytes] = []
        self.resets = 0
        self.seq = 1
        self.dictionary = build_dictionary()
        self.by_name = {f.name: f for f in self.dictionary.commands.values()}
        self.by_id = {f.msgid: f for f in self.dictionary.responses.values()}
        self.fw = VirtualFirmware(lambda: self.now, self.sent.append, settings, self._on_reset)

    def _on_reset(self) -> None:
        self.resets += 1

    def send(self, *commands: tuple[str, dict[str, int]], seq: int | None = None) -> None:
        payload = b"".join(
            self.by_name[name].encode(*(args[p] for p, _ in self.by_name[name].params))
            for name, args in commands
        )
        self.fw.receive(encode_block(self.seq if seq is None else seq, payload))
        if seq is None:
            self.seq = (self.seq + 1) & 0xF

    def cmd(self, name: str, **args: int) -> None:
        self.send((name, args))

    def advance(self, seconds: float) -> None:
        end = self.now + int(seconds * 1_000_000)
        while (wake := self.fw.next_wake()) <= end:
            self.now = max(self.now, wake)
            self.fw.run_timers()
        self.now = end
        self.fw.run_timers()

    def responses(self) -> list[tuple[int, str, dict[str, Any]]]:
        """(seq, name, params) of every block sent since the last call; name '' for acks."""
        out: list[tuple[int, str, dict[str, Any]]] = []
        for block in BlockDecoder().feed(b"".join(self.sent)):
            assert block is not None
            if not block.payload:
                out.append((block.seq, "", {}))
                continue
            fmt = self.by_id[decode_vlq(block.payload, 0)[0]]
            out.append((block.seq, fmt.name, fmt.decode(block.payload, 1)[0]))
        self.sent.clear()
        return out

    def named(self, name: str) -> list[dict[str, Any]]:
        return [p for _, n, p in self.responses() if n == name]

    def configure(self, *commands: tuple[str, dict[str, int]]) -> None:
        self.cmd("allocate_oids", count=10)
        for command in commands:
            self.send(command)
        self.cmd("finalize_config", crc=1234)
        self.responses()


def test_identify_downloads_the_dictionary() -> None:
    host = FakeHost()
    data = b""
    while True:
        host.cmd("identify", offset=len(data), count=40)
        (reply,) = host.named("identify_response")
        if not reply["data"]:
            break
        data += reply["data"]
    assert data == host.dictionary.compressed
    assert b"queue_step" in zlib.decompress(data)


def test_every_block_is_acked_after_its_response() -> None:
    host = FakeHost()
    host.cmd("get_clock")
    assert [(seq, name) for seq, name, _ in host.responses()] == [(2, "clock"), (2, "")]


def test_wrong_sequence_is_naked_with_the_expected_one() -> None:
    host = FakeHost()
    host.send(("get_clock", {}), seq=7)
    assert [(seq, name) for seq, name, _ in host.responses()] == [(1, "")]
    host.cmd("get_clock")  # the expected sequence number is still accepted
    assert [name for _, name, _ in host.responses()] == ["clock", ""]


def test_clock_is_extended_and_reported() -> None:
    host = FakeHost()
    host.now = (5 << 32) + 123
    host.cmd("get_uptime")
    assert host.named("uptime") == [{"high": 5, "clock": 123}]


def _homing_setup(host: FakeHost) -> None:
    host.configure(
        (
            "config_stepper",
            {"oid": 0, "step_pin": 0, "dir_pin": 1, "invert_step": 0, "step_pulse_ticks": 2},
        ),
        ("config_trsync", {"oid": 1}),
        ("config_endstop", {"oid": 2, "pin": 16, "pull_up": 1}),
    )


def test_homing_stops_the_stepper_at_the_trigger_clock() -> None:
    host = FakeHost()
    _homing_setup(host)
    start = 100_000
    host.cmd("reset_step_clock", oid=0, clock=start)
    host.cmd("set_next_step_dir", oid=0, dir=0)
    host.cmd("trsync_start", oid=1, report_clock=start, report_ticks=100_000, expire_reason=2)
    host.cmd("stepper_stop_on_trigger", oid=0, trsync_oid=1)
    host.cmd("trsync_set_timeout", oid=1, clock=start + 250_000)
    host.cmd(
        "endstop_home",
        oid=2,
        clock=start,
        sample_ticks=15,
        sample_count=4,
        rest_ticks=400,
        pin_value=1,
        trsync_oid=1,
        trigger_reason=1,
    )
    host.cmd("queue_step", oid=0, interval=250, count=10_000, add=0)  # 1 step per 250 ticks
    host.responses()
    host.advance(0.5)
    reports = host.named("trsync_state")
    assert reports
    assert reports[-1]["can_trigger"] == 0
    assert reports[-1]["trigger_reason"] == 1
    trigger_clock = reports[-1]["clock"]
    assert trigger_clock == start + 200_000  # 0.2 s, on the 400-tick sampling grid
    host.cmd("endstop_query_state", oid=2)
    (state,) = host.named("endstop_state")
    assert state["next_clock"] - 400 == trigger_clock
    host.cmd("stepper_get_position", oid=0)
    (pos,) = host.named("stepper_position")
    assert pos["pos"] == -((trigger_clock - start) // 250)  # dir 0 counts down


def test_homing_times_out_without_the_host_extending_it() -> None:
    host = FakeHost()
    _homing_setup(host)
    host.cmd("trsync_start", oid=1, report_clock=0, report_ticks=100_000, expire_reason=2)
    host.cmd("trsync_set_timeout", oid=1, clock=100_000)
    host.cmd(
        "endstop_home",
        oid=2,
        clock=0,
        sample_ticks=15,
        sample_count=4,
        rest_ticks=400,
        pin_value=1,
        trsync_oid=1,
        trigger_reason=1,
    )
    host.advance(0.5)
    final = host.named("trsync_state")[-1]
    assert (final["can_trigger"], final["trigger_reason"]) == (0, 2)


def test_emergency_stop_shuts_down_and_reset_reboots() -> None:
    host = FakeHost()
    _homing_setup(host)
    host.cmd("emergency_stop")
    (shutdown,) = host.named("shutdown")
    assert shutdown["static_string_id"] == host.dictionary.static_strings["Command request"]
    host.cmd("get_config")
    (config,) = host.named("config")
    assert (config["is_config"], config["is_shutdown"], config["crc"]) == (1, 1, 1234)
    host.cmd("queue_step", oid=0, interval=10, count=1, add=0)
    assert host.named("is_shutdown")
    host.cmd("reset")
    assert host.resets == 1
    assert host.responses() == []  # a resetting MCU does not ack
    host.seq = 1  # a new Klippy session starts again at sequence 1
    host.cmd("get_config")
    (config,) = host.named("config")
    assert (config["is_config"], config["is_shutdown"]) == (0, 0)


def test_heater_warms_its_sensor_and_adc_range_check_shuts_down() -> None:
    host = FakeHost(ThermalSettings(heat_factor=10, cool_factor=10))
    pin = {board.pin_name(n): n for n in range(48)}
    host.configure(
        (
            "config_digital_out",
            {
                "oid": 0,
                "pin": pin[board.HOTEND_HEATER],
                "value": 0,
                "default_value": 0,
                "max_duration": 0,
            },
        ),
        ("set_digital_out_pwm_cycle", {"oid": 0, "cycle_ticks": 100_000}),
        ("config_analog_in", {"oid": 1, "pin": pin[board.HOTEND_SENSOR]}),
    )
    # Shut down once the reading drops below the 150 C mark (hotter = lower ADC value).
    limit = thermal.adc_sum(150, 4095, 8)
    host.cmd(
        "query_analog_in",
        oid=1,
        clock=0,
        sample_ticks=1000,
        sample_count=8,
        rest_ticks=300_000,
        min_value=limit,
        max_value=65535,
        range_check_count=4,
    )
    host.cmd("queue_digital_out", oid=0, clock=0, on_ticks=100_000)
    host.advance(1.0)
    values = [r["value"] for r in host.named("analog_in_state")]
    assert values == sorted(values, reverse=True)
    assert values[0] > values[-1]
    host.advance(10.0)
    (shutdown,) = host.named("shutdown")
    assert shutdown["static_string_id"] == host.dictionary.static_strings["ADC out of range"]
    assert host.fw.heaters[board.HOTEND_HEATER].duty == 0.0


def test_heater_left_on_without_updates_shuts_down() -> None:
    host = FakeHost()
    pin = next(n for n in range(48) if board.pin_name(n) == board.BED_HEATER)
    host.configure(
        (
            "config_digital_out",
            {"oid": 0, "pin": pin, "value": 0, "default_value": 0, "max_duration": 5_000_000},
        )
    )
    host.cmd("queue_digital_out", oid=0, clock=1000, on_ticks=1)
    host.advance(4.0)
    host.cmd("queue_digital_out", oid=0, clock=host.now + 1000, on_ticks=1)
    host.advance(4.0)
    assert host.named("shutdown") == []
    host.advance(2.0)
    (shutdown,) = host.named("shutdown")
    reason = host.dictionary.static_strings["Missed scheduling of next digital out event"]
    assert shutdown["static_string_id"] == reason


def test_wrong_oid_type_shuts_down() -> None:
    host = FakeHost()
    _homing_setup(host)
    host.cmd("queue_step", oid=1, interval=10, count=1, add=0)  # oid 1 is a trsync
    (shutdown,) = host.named("shutdown")
    assert shutdown["static_string_id"] == host.dictionary.static_strings["Invalid oid type"]


# ----- printer.cfg ----------------------------------------------------------------------------


def _cfg(**changes: Any) -> configparser.ConfigParser:
    spec = PrinterSpec(mcu_serial="/tmp/klipper_host_x", gcodes_dir="/data/gcodes", **changes)
    parser = configparser.ConfigParser(interpolation=None)
    parser.read_string(render_printer_cfg(spec))
    return parser


def test_printer_cfg_matches_the_board() -> None:
    cfg = _cfg(size_x=300, nozzle_diameter=0.6)
    assert cfg["printer"]["kinematics"] == "corexy"
    assert cfg["stepper_x"]["endstop_pin"] == "^" + board.STEPPER_X.endstop
    assert cfg["stepper_x"]["position_max"] == "300"
    assert cfg["stepper_z"]["position_endstop"] == "0"
    assert cfg["extruder"]["heater_pin"] == board.HOTEND_HEATER
    assert cfg["extruder"]["sensor_pin"] == board.HOTEND_SENSOR
    assert cfg["extruder"]["nozzle_diameter"] == "0.6"
    assert cfg["heater_bed"]["control"] == "watermark"
    assert cfg["virtual_sdcard"]["path"] == "/data/gcodes"
    assert cfg["idle_timeout"]["timeout"] == "3600"
    assert {"pause_resume", "display_status", "respond", "exclude_object", "fan"} <= set(cfg)
    # Klippy rejects restart_method for /tmp/klipper_host_ paths; it resets by command anyway.
    assert "restart_method" not in cfg["mcu"]


def test_printer_cfg_restart_method_for_other_serial_paths() -> None:
    text = render_printer_cfg(PrinterSpec(mcu_serial="/dev/ttyACM0", gcodes_dir="/g"))
    assert "restart_method: command" in text


@pytest.mark.parametrize(
    "changes",
    [
        {"mcu_serial": "/tmp/x\n[mcu]"},
        {"gcodes_dir": "/g # comment"},
        {"size_x": 0.0},
        {"max_velocity": float("nan")},
        {"min_extrude_temp": -1.0},
    ],
)
def test_printer_spec_rejects_bad_values(changes: dict[str, Any]) -> None:
    values: dict[str, Any] = {"mcu_serial": "/tmp/klipper_host_x", "gcodes_dir": "/g", **changes}
    with pytest.raises(ValueError, match=r"mcu_serial|gcodes_dir|out of range"):
        PrinterSpec(**values)
