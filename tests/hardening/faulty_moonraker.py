"""FAULT-INJECTION stand-in — not Moonraker; only for faults a real Moonraker cannot produce
on demand.

Everything a real Moonraker *can* do (restart, lose Klippy, refuse a key) is tested against
real Moonraker. This small ``websockets`` server on 127.0.0.1 speaks just enough of the
protocol for a :class:`~kybercore.moonraker.session.MoonrakerSession` to come online
(``server.connection.identify``, ``server.info`` with Klippy ready,
``printer.objects.subscribe``), streams a ``notify_status_update`` every ``interval``
seconds, and then misbehaves as its scenario says, on every connection:

``healthy``     nothing wrong (a second printer, or a baseline)
``malformed``   frames that are not JSON, or not JSON-RPC, between good deltas
``unknown``     notifications no Moonraker sends, between good deltas
``bad_shapes``  JSON-RPC of the wrong shape: objects that are not dicts, error codes that
                are not numbers, ids that are not ints
``bad_info``    answers ``server.info`` with a list and ``subscribe`` with a string
``bad_fields``  deltas whose objects are fine but whose fields have the wrong type
``huge``        one 50 MB frame right after the subscription
``silent``      after a few deltas, stops reading its socket and sending: pings go
                unanswered, but the TCP connection stays open
``stall``       accepts TCP and never answers the WebSocket upgrade (plain asyncio server)

Run it alone (``python -m tests.hardening.faulty_moonraker huge``) to keep its memory out of
a measurement: it prints ``PORT <n>`` and serves until killed.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import json
import sys
import time
from typing import Any, Final

import websockets
from websockets.asyncio.server import Server, ServerConnection, serve

SCENARIOS: Final = (
    "healthy",
    "malformed",
    "unknown",
    "bad_shapes",
    "bad_info",
    "bad_fields",
    "huge",
    "silent",
    "stall",
)
HUGE_BYTES: Final = 50 * 1024 * 1024

# Frames that are not JSON, or JSON that is not a JSON-RPC message.
MALFORMED: Final[tuple[str | bytes, ...]] = (
    '{"jsonrpc": "2.0", "method": "notify_status_upd',
    "}{",
    "",
    "\x00\x01garbage",
    b"\xff\xfe\x00 binary junk",
    b'{"jsonrpc": "2.0", "method": "notify_status_update", "params": [{"extruder": {}}]',
    "[1, 2, 3]",
    "42",
    '"a string"',
    "null",
    "NaN",
    '{"id": 999999, "result": {}}',
    '{"id": "1", "result": {}}',
    '{"id": [1], "result": {}}',
    '{"id": null, "error": {"code": -32600, "message": "Invalid Request"}}',
    '{"method": 5, "params": []}',
    '{"method": null}',
    '{"jsonrpc": "2.0"}',
    '{"params": [{"extruder": {"temperature": 999}}]}',
    '{"method": "notify_status_update", "params": "nope"}',
    '{"method": "notify_status_update", "params": {"extruder": {"temperature": 1}}}',
    '{"method": "notify_status_update", "params": []}',
    '{"method": "notify_status_update", "params": [[1, 2]]}',
    '{"method": "notify_status_update", "params": [{"extruder": {"temperature": 1}}, "late"]}',
)

UNKNOWN: Final[tuple[str, ...]] = tuple(
    json.dumps({"jsonrpc": "2.0", "method": method, "params": params})
    for method, params in (
        ("notify_moonraker_v99_feature", [{"anything": True}]),
        ("notify_proc_stat_update", [{"moonraker_stats": {"cpu_usage": 1.5}}]),
        ("notify_" + "x" * 10_000, []),
        ("notify_klippy_something_new", [1, 2, 3]),
        ("not_a_notification", None),
        ("notify_status_update", [{"objects_we_never_asked_for": {"field": [1, {"a": 2}]}}]),
        ("notify_history_changed", [{"action": "added", "job": {}}]),
    )
)

# Well-formed JSON-RPC of the wrong shape: a delta object that is not a dict, and so on.
BAD_SHAPES: Final[tuple[str, ...]] = tuple(
    json.dumps(frame)
    for frame in (
        {"method": "notify_status_update", "params": [{"extruder": 5}, 1.0]},
        {"method": "notify_status_update", "params": [{"extruder": [1, 2]}, 1.0]},
        {"method": "notify_status_update", "params": [{"extruder": None, "heater_bed": "hot"}]},
        {"method": "notify_status_update", "params": [{"webhooks": {"state": 5}}]},
        {"method": "notify_status_update", "params": [{"print_stats": {"filename": 7}}]},
        {"method": "notify_status_update", "params": [5, 1.0]},
        {"method": "notify_klippy_ready", "params": "soon"},
        {"method": "notify_gcode_response", "params": [{"not": "a string"}]},
        {"method": "notify_gcode_response", "params": []},
    )
)

# Objects of the right shape, fields of the wrong type (a progress that is not a number...).
BAD_FIELDS: Final[tuple[str, ...]] = tuple(
    json.dumps({"method": "notify_status_update", "params": [delta, 1.0]})
    for delta in (
        {"display_status": {"progress": "half"}},
        {"print_stats": {"print_duration": "long", "total_duration": [1]}},
        {"print_stats": {"info": [1, 2]}},
        {"toolhead": {"position": ["a", "b"], "homed_axes": 7}},
        {"virtual_sdcard": {"progress": {"a": 1}}},
    )
)


class FaultyMoonraker:
    """FAULT-INJECTION stand-in — not Moonraker; only for faults a real Moonraker cannot
    produce on demand. See the module docstring for the scenarios."""

    def __init__(self, scenario: str, *, interval: float = 0.05, silent_after: int = 5) -> None:
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; one of {', '.join(SCENARIOS)}")
        self.scenario = scenario
        self.interval = interval
        self.silent_after = silent_after
        self.port = 0
        self.connections = 0
        """TCP connections accepted (each one is a session attempt)."""
        self.connected_at: list[float] = []
        """``time.monotonic()`` of every connection accepted."""
        self.subscriptions = 0
        self.junk_sent = 0
        """Junk frames sent so far (the scenario's list, cycled), over every connection."""
        self.huge_frames_sent = 0
        self.silenced_at: list[float] = []
        """``time.monotonic()`` of every moment a connection went silent."""
        self.methods: list[str] = []
        self.configfile: dict[str, Any] | None = None
        """Klippy's ``configfile.settings`` to answer ``printer.objects.query`` with; while
        None, that query fails as it does while Klippy cannot answer."""
        self._server: Server | asyncio.Server | None = None
        self._stalled: list[asyncio.StreamWriter] = []
        self._open: set[ServerConnection] = set()
        self._tasks: set[asyncio.Task[None]] = set()
        self._huge: str | None = None

    @property
    def url(self) -> str:
        """Its base URL, as printers.json would hold it."""
        return f"http://127.0.0.1:{self.port}"

    async def start(self) -> None:
        """Listen on an ephemeral port of 127.0.0.1."""
        if self.scenario == "stall":
            server = await asyncio.start_server(self._stall, "127.0.0.1", 0)
            self._server = server
            self.port = server.sockets[0].getsockname()[1]
            return
        ws_server = await serve(
            self._serve,
            "127.0.0.1",
            0,
            max_size=None,
            ping_interval=None,  # a real Moonraker does not ping its clients either
            compression=None,
        )
        self._server = ws_server
        self.port = next(iter(ws_server.sockets)).getsockname()[1]

    async def stop(self) -> None:
        """Close every connection and stop listening."""
        for writer in self._stalled:
            writer.close()
        for ws in list(self._open):  # a silent connection would never finish a close handshake
            ws.transport.abort()
        for task in list(self._tasks):
            task.cancel()
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 5)

    # -- scenarios ---------------------------------------------------------------------

    async def _stall(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """Accept the TCP connection, read the upgrade request, never answer it."""
        self.connections += 1
        self.connected_at.append(time.monotonic())
        self._stalled.append(writer)
        with contextlib.suppress(ConnectionError):
            while await reader.read(65536):
                pass

    async def _serve(self, ws: ServerConnection) -> None:
        self.connections += 1
        self.connected_at.append(time.monotonic())
        self._open.add(ws)
        streamer: asyncio.Task[None] | None = None
        try:
            async for frame in ws:
                request = json.loads(frame)
                method = request.get("method", "")
                self.methods.append(method)
                answer = self._answer(request)
                if answer is not None:
                    await ws.send(json.dumps(answer))
                if method == "printer.objects.subscribe" and streamer is None:
                    self.subscriptions += 1
                    streamer = asyncio.create_task(self._stream(ws))
                    self._tasks.add(streamer)
                    streamer.add_done_callback(self._tasks.discard)
        except websockets.ConnectionClosed:
            pass
        finally:
            self._open.discard(ws)
            if streamer is not None:
                streamer.cancel()

    def _answer(self, request: dict[str, Any]) -> dict[str, Any] | None:
        method, req_id = request.get("method"), request.get("id")
        result: Any
        if method == "server.connection.identify":
            result = {"connection_id": self.connections}
        elif method == "server.info":
            result = (
                ["not", "a", "dict"]
                if self.scenario == "bad_info"
                else {
                    "klippy_connected": True,
                    "klippy_state": "ready",
                    "components": [],
                    "moonraker_version": "fault-injection-stand-in",
                }
            )
        elif method == "printer.objects.subscribe":
            if self.scenario == "bad_info":
                result = "not a status"
            else:
                result = {"eventtime": time.monotonic(), "status": _status(20.0)}
        elif method == "printer.gcode.script" and self.scenario == "bad_shapes":
            return {"jsonrpc": "2.0", "id": req_id, "error": {"code": "E42", "message": None}}
        elif method == "printer.objects.query" and self.configfile is not None:
            result = {
                "eventtime": time.monotonic(),
                "status": {"configfile": {"settings": self.configfile}},
            }
        elif method == "printer.info":
            result = {"state": "ready", "state_message": "Printer is ready"}
        else:
            return {
                "jsonrpc": "2.0",
                "id": req_id,
                "error": {"code": -32601, "message": f"Method not found: {method}"},
            }
        return {"jsonrpc": "2.0", "id": req_id, "result": result}

    async def _stream(self, ws: ServerConnection) -> None:
        junk: tuple[str | bytes, ...] = {
            "malformed": MALFORMED,
            "unknown": UNKNOWN,
            "bad_shapes": BAD_SHAPES,
            "bad_fields": BAD_FIELDS,
        }.get(self.scenario, ())
        extra = itertools.cycle(junk) if junk else None
        with contextlib.suppress(websockets.ConnectionClosed):
            if self.scenario == "huge":
                self.huge_frames_sent += 1
                await ws.send(self._huge_frame())
            for tick in itertools.count():
                if self.scenario == "silent" and tick >= self.silent_after:
                    # Stop reading (pings go unanswered) and stop talking; keep TCP open.
                    ws.transport.pause_reading()
                    self.silenced_at.append(time.monotonic())
                    await asyncio.Event().wait()
                if extra is not None:
                    await ws.send(next(extra))
                    self.junk_sent += 1
                await ws.send(_delta(20.0 + tick / 1000))
                await asyncio.sleep(self.interval)  # stand-in: paces its stream as Moonraker does

    def _huge_frame(self) -> str:
        if self._huge is None:
            head = '{"jsonrpc": "2.0", "method": "notify_status_update", "params": [{"extruder": '
            head += '{"blob": "'
            tail = '"}}, 1.0]}'
            self._huge = head + "x" * (HUGE_BYTES - len(head) - len(tail)) + tail
        return self._huge


def _status(temperature: float) -> dict[str, Any]:
    return {
        "webhooks": {"state": "ready", "state_message": "Printer is ready"},
        "extruder": {"temperature": temperature, "target": 0.0, "power": 0.0},
        "heater_bed": {"temperature": 20.0, "target": 0.0, "power": 0.0},
        "print_stats": {"state": "standby", "filename": ""},
    }


def _delta(temperature: float) -> str:
    params = [{"extruder": {"temperature": temperature}}, time.monotonic()]
    return json.dumps({"jsonrpc": "2.0", "method": "notify_status_update", "params": params})


async def _main(scenario: str) -> None:
    standin = FaultyMoonraker(scenario)
    await standin.start()
    print(f"PORT {standin.port}", flush=True)
    reported = 0
    while True:  # tell the parent about every connection and 50 MB frame
        await asyncio.sleep(0.05)  # stand-in: reports its counters every 50 ms
        if standin.connections + standin.huge_frames_sent != reported:
            reported = standin.connections + standin.huge_frames_sent
            print(f"CONNECTIONS {standin.connections} HUGE {standin.huge_frames_sent}", flush=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", choices=SCENARIOS)
    args = parser.parse_args()
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_main(args.scenario))
    sys.exit(0)
