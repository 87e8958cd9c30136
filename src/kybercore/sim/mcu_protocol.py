"""Klipper's MCU wire protocol: block framing, CRC, VLQ integers and the data dictionary.

Pure functions and data only; the virtual MCU does the I/O. A block on the wire is
``len, 0x10|seq, payload, crc16 (2 bytes), 0x7E``; the payload is a sequence of messages, each a
message id followed by its parameters, every integer VLQ-encoded.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Final

from kybercore.sim import board

MESSAGE_MIN: Final = 5
MESSAGE_MAX: Final = 64
MESSAGE_PAYLOAD_MAX: Final = MESSAGE_MAX - MESSAGE_MIN
MESSAGE_SEQ_MASK: Final = 0x0F
MESSAGE_DEST: Final = 0x10
MESSAGE_SYNC: Final = 0x7E

# Klippy parses message ids as a single byte, so every id must be a one-byte VLQ.
_MAX_MSGID: Final = 95

CLOCK_FREQ: Final = 1_000_000
ADC_MAX: Final = 4095
PWM_MAX: Final = 255
STATS_SUMSQ_BASE: Final = 256
MOVE_COUNT: Final = 1024

# The first two ids are fixed by the protocol: Klippy uses them before it has the dictionary.
IDENTIFY_RESPONSE: Final = "identify_response offset=%u data=%.*s"
IDENTIFY: Final = "identify offset=%u count=%c"

COMMANDS: Final = (
    IDENTIFY,
    "get_uptime",
    "get_clock",
    "get_config",
    "allocate_oids count=%c",
    "finalize_config crc=%u",
    "emergency_stop",
    "reset",
    "clear_shutdown",
    "config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u",
    "queue_step oid=%c interval=%u count=%hu add=%hi",
    "set_next_step_dir oid=%c dir=%c",
    "reset_step_clock oid=%c clock=%u",
    "stepper_get_position oid=%c",
    "stepper_stop_on_trigger oid=%c trsync_oid=%c",
    "config_endstop oid=%c pin=%c pull_up=%c",
    "endstop_home oid=%c clock=%u sample_ticks=%u sample_count=%c rest_ticks=%u"
    " pin_value=%c trsync_oid=%c trigger_reason=%c",
    "endstop_query_state oid=%c",
    "config_trsync oid=%c",
    "trsync_start oid=%c report_clock=%u report_ticks=%u expire_reason=%c",
    "trsync_set_timeout oid=%c clock=%u",
    "trsync_trigger oid=%c reason=%c",
    "config_digital_out oid=%c pin=%u value=%c default_value=%c max_duration=%u",
    "set_digital_out_pwm_cycle oid=%c cycle_ticks=%u",
    "queue_digital_out oid=%c clock=%u on_ticks=%u",
    "update_digital_out oid=%c value=%c",
    "set_digital_out pin=%u value=%c",
    "config_analog_in oid=%c pin=%u",
    "query_analog_in oid=%c clock=%u sample_ticks=%u sample_count=%c rest_ticks=%u"
    " min_value=%hu max_value=%hu range_check_count=%c",
)

RESPONSES: Final = (
    IDENTIFY_RESPONSE,
    "uptime high=%u clock=%u",
    "clock clock=%u",
    "config is_config=%c crc=%u is_shutdown=%c move_count=%hu",
    "shutdown clock=%u static_string_id=%hu",
    "is_shutdown static_string_id=%hu",
    "stats count=%u sum=%u sumsq=%u",
    "stepper_position oid=%c pos=%i",
    "endstop_state oid=%c homing=%c next_clock=%u pin_value=%c",
    "trsync_state oid=%c can_trigger=%c trigger_reason=%c clock=%u",
    "analog_in_state oid=%c next_clock=%u value=%hu",
)

# Shutdown reasons travel as ids; Klippy maps them back through the dictionary.
STATIC_STRINGS: Final = (
    "Command request",
    "ADC out of range",
    "Missed scheduling of next digital out event",
    "Invalid oid type",
    "Can't assign oid",
    "Invalid command",
    "Shutdown cleared when not shutdown",
)

# Width and signedness of each integer type: (bits, signed).
_INT_TYPES: Final = {
    "%u": (32, False),
    "%i": (32, True),
    "%hu": (16, False),
    "%hi": (16, True),
    "%c": (8, False),
}
_BYTES_TYPES: Final = ("%s", "%.*s", "%*s")

Value = int | bytes


class ProtocolError(ValueError):
    """A message that cannot be encoded or decoded."""


def crc16_ccitt(data: bytes | bytearray) -> int:
    """The CRC-16/MCRF4XX (reflected CCITT, init 0xFFFF) Klipper appends to every block."""
    crc = 0xFFFF
    for byte in data:
        byte ^= crc & 0xFF
        byte ^= (byte & 0x0F) << 4
        crc = ((byte << 8) | (crc >> 8)) ^ (byte >> 4) ^ (byte << 3)
        crc &= 0xFFFF
    return crc


def encode_vlq(value: int) -> bytes:
    """Encode a 32-bit integer (signed or unsigned) in Klipper's variable-length format."""
    value = _to_signed32(value)
    out = bytearray()
    # Each threshold is where the value no longer fits the bytes emitted below it; the top
    # bits of the first byte carry the sign, which is why the ranges are asymmetric.
    for shift, high, low in (
        (28, 0xC000000, -0x4000000),
        (21, 0x180000, -0x80000),
        (14, 0x3000, -0x1000),
        (7, 0x60, -0x20),
    ):
        if value >= high or value < low:
            out.append(((value >> shift) & 0x7F) | 0x80)
    out.append(value & 0x7F)
    return bytes(out)


def decode_vlq(data: bytes | bytearray, pos: int) -> tuple[int, int]:
    """Decode one VLQ integer at `pos`; returns (signed value, next position)."""
    try:
        byte = data[pos]
        pos += 1
        value = byte & 0x7F
        if byte & 0x60 == 0x60:
            value |= -0x20
        while byte & 0x80:
            byte = data[pos]
            pos += 1
            value = (value << 7) | (byte & 0x7F)
    except IndexError as exc:
        raise ProtocolError("truncated integer") from exc
    return _to_signed32(value), pos


def _to_signed32(value: int) -> int:
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value & 0x80000000 else value


def _fit(value: int, bits: int, signed: bool) -> int:
    value &= (1 << bits) - 1
    if signed and value & (1 << (bits - 1)):
        value -= 1 << bits
    return value


@dataclass(frozen=True)
class MessageFormat:
    """One command or response: its id and its Klipper format string."""

    msgid: int
    format: str

    @property
    def name(self) -> str:
        """The message name (first word of the format)."""
        return self.format.split()[0]

    @cached_property
    def params(self) -> list[tuple[str, str]]:
        """(name, type code) of each parameter, in wire order."""
        return [
            (name, code) for name, code in (part.split("=", 1) for part in self.format.split()[1:])
        ]

    def encode(self, *values: Value) -> bytes:
        """The message id followed by `values` in parameter order."""
        params = self.params
        if len(values) != len(params):
            raise ProtocolError(f"{self.name} takes {len(params)} values, got {len(values)}")
        out = bytearray(encode_vlq(self.msgid))
        for (name, code), value in zip(params, values, strict=True):
            if code in _BYTES_TYPES:
                if not isinstance(value, bytes) or len(value) > MESSAGE_PAYLOAD_MAX:
                    raise ProtocolError(f"{self.name}.{name} needs a short bytes value")
                out.append(len(value))
                out += value
            elif isinstance(value, int):
                out += encode_vlq(value)
            else:
                raise ProtocolError(f"{self.name}.{name} needs an integer")
        return bytes(out)

    def decode(self, data: bytes | bytearray, pos: int) -> tuple[dict[str, Value], int]:
        """Parse the parameters that follow this message's id at `pos`."""
        values: dict[str, Value] = {}
        for name, code in self.params:
            if code in _BYTES_TYPES:
                if pos >= len(data) or pos + 1 + data[pos] > len(data):
                    raise ProtocolError(f"truncated {self.name}.{name}")
                length = data[pos]
                values[name] = bytes(data[pos + 1 : pos + 1 + length])
                pos += 1 + length
            else:
                raw, pos = decode_vlq(data, pos)
                bits, signed = _INT_TYPES[code]
                values[name] = _fit(raw, bits, signed)
        return values, pos


@dataclass(frozen=True)
class DataDictionary:
    """The message set the virtual MCU speaks, and its compressed JSON form for `identify`."""

    commands: Mapping[int, MessageFormat]
    responses: Mapping[str, MessageFormat]
    static_strings: Mapping[str, int]
    compressed: bytes

    def response(self, name: str, *values: Value) -> bytes:
        """Encode the response `name` with `values`."""
        return self.responses[name].encode(*values)


def build_dictionary(
    commands: Sequence[str] = COMMANDS,
    responses: Sequence[str] = RESPONSES,
    static_strings: Sequence[str] = STATIC_STRINGS,
    version: str = "kybercore-virtual-mcu",
) -> DataDictionary:
    """Assign message ids and produce the dictionary Klippy downloads through `identify`."""
    fixed = {IDENTIFY_RESPONSE: 0, IDENTIFY: 1}
    ids: dict[str, int] = dict(fixed)
    for fmt in (*responses, *commands):
        if fmt not in ids:
            ids[fmt] = len(ids)
    if len(ids) - 1 > _MAX_MSGID:
        raise ProtocolError("too many messages for one-byte ids")
    strings = {text: index for index, text in enumerate(static_strings)}
    document = {
        "version": version,
        "build_versions": "python",
        "commands": {fmt: ids[fmt] for fmt in commands},
        "responses": {fmt: ids[fmt] for fmt in responses},
        "enumerations": {"pin": board.pin_enumeration(), "static_string_id": strings},
        "config": {
            "CLOCK_FREQ": CLOCK_FREQ,
            "MCU": "kybercore_virtual",
            "STATS_SUMSQ_BASE": STATS_SUMSQ_BASE,
            "ADC_MAX": ADC_MAX,
            "PWM_MAX": PWM_MAX,
        },
    }
    raw = json.dumps(document, separators=(",", ":")).encode()
    return DataDictionary(
        commands={ids[fmt]: MessageFormat(ids[fmt], fmt) for fmt in commands},
        responses={MessageFormat(0, fmt).name: MessageFormat(ids[fmt], fmt) for fmt in responses},
        static_strings=strings,
        compressed=zlib.compress(raw, 9),
    )


def encode_block(seq: int, payload: bytes) -> bytes:
    """Frame `payload` (at most 59 bytes) as one block carrying sequence number `seq`."""
    if len(payload) > MESSAGE_PAYLOAD_MAX:
        raise ProtocolError(f"payload of {len(payload)} bytes does not fit a block")
    head = bytes((len(payload) + MESSAGE_MIN, MESSAGE_DEST | (seq & MESSAGE_SEQ_MASK))) + payload
    crc = crc16_ccitt(head)
    return head + bytes((crc >> 8, crc & 0xFF, MESSAGE_SYNC))


@dataclass(frozen=True)
class Block:
    """One well-formed block received from the host."""

    seq: int
    payload: bytes


class BlockDecoder:
    """Splits a byte stream into blocks; after a corrupt block it skips to the next sync byte."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._need_sync = False

    def reset(self) -> None:
        """Forget any partial input."""
        self._buf.clear()
        self._need_sync = False

    def feed(self, data: bytes) -> list[Block | None]:
        """Add received bytes; returns complete blocks in order, None for each corrupt one."""
        self._buf += data
        out: list[Block | None] = []
        while True:
            if self._need_sync:
                end = self._buf.find(MESSAGE_SYNC)
                if end < 0:
                    self._buf.clear()
                    return out
                del self._buf[: end + 1]
                self._need_sync = False
            if not self._buf:
                return out
            if self._buf[0] == MESSAGE_SYNC:
                # The host sends a bare sync byte before retransmissions.
                del self._buf[0]
                continue
            length = self._buf[0]
            if not MESSAGE_MIN <= length <= MESSAGE_MAX:
                self._corrupt(out)
                continue
            if len(self._buf) < 2:
                return out
            if self._buf[1] & ~MESSAGE_SEQ_MASK != MESSAGE_DEST:
                self._corrupt(out)
                continue
            if len(self._buf) < length:
                return out
            block = bytes(self._buf[:length])
            crc = crc16_ccitt(block[:-3])
            if block[-1] != MESSAGE_SYNC or block[-3:-1] != bytes((crc >> 8, crc & 0xFF)):
                self._corrupt(out)
                continue
            del self._buf[:length]
            out.append(Block(block[1] & MESSAGE_SEQ_MASK, block[2:-3]))

    def _corrupt(self, out: list[Block | None]) -> None:
        out.append(None)
        self._need_sync = True
