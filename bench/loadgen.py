"""LOAD GENERATOR — not Moonraker. A benchmark-only stand-in serving N printers.

One process, one event loop, one listening socket per printer on 127.0.0.1 (an ephemeral
port each, so every printer has its own base URL as on a real farm). Each port speaks the
slice of Moonraker's protocol KyberCore uses, HTTP and the WebSocket upgrade on the same
port: ``server.connection.identify``, ``server.info``, ``printer.objects.subscribe`` and
``query``, ``server.files.metadata``, print actions. Every subscribed printer then sends a
``notify_status_update`` 4 times a second (:mod:`bench.printer_model`).

Why not ``websockets`` or uvicorn here: at N = 5,000 this process writes 20,000 frames/s,
and on a 2-core machine every cycle it spends is taken from the process being measured.
A raw :class:`asyncio.Protocol` with :mod:`bench.wsframes` costs a few microseconds a frame.

Run by :mod:`bench.fleet_scale`; standalone: ``python -m bench.loadgen --printers 10``.
It prints one JSON line ``{"ports": [...]}`` when ready, then reads commands on stdin:
``dump PATH`` writes every printer's send times (see :meth:`LoadGenerator.dump`);
end of input, or ``--max-seconds``, stops it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import socket
import sys
import time
from array import array
from pathlib import Path
from typing import Any, Final
from urllib.parse import parse_qs, urlsplit

import orjson

from bench import wsframes
from bench.printer_model import UPDATES_PER_SECOND, SimPrinter, configfile_settings

BANNER: Final = "LOAD GENERATOR — not Moonraker"
# Printers are spread over this many emission slots per 250 ms period (one every 10 ms),
# so the fleet's updates are evenly spaced rather than all at once.
SLOTS: Final = 25
_OK_METHODS: Final = frozenset(
    {
        "printer.emergency_stop",
        "printer.restart",
        "printer.firmware_restart",
        "printer.gcode.script",
    }
)
_PRINT_ACTIONS: Final = frozenset({"start", "pause", "resume", "cancel"})
_REASONS: Final = {200: "OK", 400: "Bad Request", 404: "Not Found"}
_connection_ids = itertools.count(1)


class RpcError(Exception):
    """A JSON-RPC error (also answered over HTTP with the same code)."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


class Endpoint:
    """One printer: its simulated state, who subscribed, when each update left."""

    def __init__(self, index: int, port: int) -> None:
        self.printer = SimPrinter(index)
        self.port = port
        self.subscribers: set[Connection] = set()
        self.sent_at = array("d")
        """``sent_at[seq - 1]`` is the monotonic time update ``seq`` was written."""

    def call(self, method: str, params: dict[str, Any], conn: Connection | None) -> Any:
        """Answer one Moonraker method (JSON-RPC or its HTTP twin)."""
        printer = self.printer
        if method == "server.connection.identify":
            return {"connection_id": next(_connection_ids)}
        if method == "server.info":
            return {
                "klippy_connected": True,
                "klippy_state": "ready",
                "components": ["klippy_apis", "file_manager", "history"],
                "failed_components": [],
                "warnings": [],
                "websocket_count": len(self.subscribers),
                "moonraker_version": BANNER,
                "api_version_string": "1.5.0",
            }
        if method == "printer.info":
            return {"state": "ready", "state_message": "Printer is ready", "hostname": "loadgen"}
        if method in ("printer.objects.query", "printer.objects.subscribe"):
            objects = params.get("objects")
            status = printer.status(objects if isinstance(objects, dict) else None)
            if "configfile" in (objects or {}):
                status["configfile"] = {"settings": configfile_settings()}
            if method == "printer.objects.subscribe" and conn is not None:
                self.subscribers.add(conn)
            return {"eventtime": time.monotonic(), "status": status}
        if method == "server.files.metadata":
            return printer.metadata(str(params.get("filename", "")))
        # What KyberCore's ledger reads at each connection. History is a core component of
        # Moonraker: answering "not found" had every printer retried, with a warning each,
        # during the measured window.
        if method == "server.database.get_item" and params.get("key") == "instance_id":
            return {"namespace": "moonraker", "key": "instance_id", "value": f"lg-{self.port}"}
        if method == "server.history.list":
            return {"count": 0, "jobs": []}
        action = method.removeprefix("printer.print.")
        if action in _PRINT_ACTIONS:
            printer.act(action)
            return "ok"
        if method in _OK_METHODS:
            return "ok"
        raise RpcError(-32601 if conn else 404, f"Method not found: {method}")

    def emit(self) -> None:
        """Send the next status update to every subscriber."""
        if not self.subscribers:
            return
        before = self.printer.seq
        delta = self.printer.step()
        message = {
            "jsonrpc": "2.0",
            "method": "notify_status_update",
            "params": [delta, time.monotonic()],
        }
        frame = wsframes.encode(orjson.dumps(message))
        sent = time.monotonic()
        for conn in self.subscribers:
            conn.write(frame)
        if self.printer.seq != before:
            self.sent_at.append(sent)


class Connection(asyncio.Protocol):
    """One TCP connection: HTTP/1.1 requests until it upgrades to a WebSocket."""

    def __init__(self, generator: LoadGenerator) -> None:
        self._generator = generator
        self._buffer = bytearray()
        self._websocket = False
        self._transport: asyncio.Transport | None = None
        self._endpoint: Endpoint | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport
        port = transport.get_extra_info("sockname")[1]
        self._endpoint = self._generator.by_port[port]

    def connection_lost(self, exc: Exception | None) -> None:
        if self._endpoint is not None:
            self._endpoint.subscribers.discard(self)
        self._transport = None

    def write(self, data: bytes) -> None:
        """Queue bytes for the peer (dropped once the connection is gone)."""
        if self._transport is not None:
            self._transport.write(data)

    def data_received(self, data: bytes) -> None:
        self._buffer += data
        if not self._websocket:
            self._serve_http()
        if self._websocket:
            self._serve_frames()

    # -- HTTP --------------------------------------------------------------------------

    def _serve_http(self) -> None:
        while not self._websocket and self._transport is not None:
            end = self._buffer.find(b"\r\n\r\n")
            if end < 0:
                return
            head = bytes(self._buffer[:end]).decode("latin-1").split("\r\n")
            headers = dict(_header(line) for line in head[1:] if ":" in line)
            length = int(headers.get("content-length", "0"))
            if len(self._buffer) < end + 4 + length:
                return
            del self._buffer[: end + 4 + length]
            method, target, _version = head[0].split(" ", 2)
            if headers.get("upgrade", "").lower() == "websocket":
                self._upgrade(headers["sec-websocket-key"])
            else:
                self._answer_http(method, target)
                if headers.get("connection", "").lower() == "close":
                    self._transport.close()

    def _upgrade(self, key: str) -> None:
        self.write(
            b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            b"Sec-WebSocket-Accept: " + wsframes.accept_key(key).encode() + b"\r\n\r\n"
        )
        self._websocket = True

    def _answer_http(self, verb: str, target: str) -> None:
        assert self._endpoint is not None
        url = urlsplit(target)
        query = {k: v[0] for k, v in parse_qs(url.query, keep_blank_values=True).items()}
        method = url.path.strip("/").replace("/", ".")
        params: dict[str, Any] = dict(query)
        if method == "printer.objects.query":
            params = {"objects": {k: v.split(",") if v else None for k, v in query.items()}}
        try:
            if verb not in ("GET", "POST"):
                raise RpcError(404, f"{verb} is not served here")
            status, body = 200, {"result": self._endpoint.call(method, params, None)}
        except RpcError as exc:
            status = 404 if exc.code in (404, -32601) else 400
            body = {"error": {"code": status, "message": exc.message}}
        payload = orjson.dumps(body)
        self.write(
            f"HTTP/1.1 {status} {_REASONS[status]}\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(payload)}\r\n\r\n".encode()
            + payload
        )

    # -- WebSocket ---------------------------------------------------------------------

    def _serve_frames(self) -> None:
        while (frame := wsframes.decode(self._buffer)) is not None:
            if frame.opcode == wsframes.TEXT:
                self._answer_rpc(frame.payload)
            elif frame.opcode == wsframes.PING:
                self.write(wsframes.encode(frame.payload, wsframes.PONG))
            elif frame.opcode == wsframes.CLOSE:
                self.write(wsframes.encode(frame.payload[:2], wsframes.CLOSE))
                if self._transport is not None:
                    self._transport.close()
                return

    def _answer_rpc(self, payload: bytes) -> None:
        assert self._endpoint is not None
        request = orjson.loads(payload)
        params = request.get("params")
        answer: dict[str, Any] = {"jsonrpc": "2.0", "id": request.get("id")}
        try:
            method = str(request.get("method"))
            args = params if isinstance(params, dict) else {}
            answer["result"] = self._endpoint.call(method, args, self)
        except RpcError as exc:
            answer["error"] = {"code": exc.code, "message": exc.message}
        self.write(wsframes.encode(orjson.dumps(answer)))


def _header(line: str) -> tuple[str, str]:
    name, _, value = line.partition(":")
    return name.strip().lower(), value.strip()


class LoadGenerator:
    """N endpoints and the clock that makes them emit."""

    def __init__(self) -> None:
        self.endpoints: list[Endpoint] = []
        self.by_port: dict[int, Endpoint] = {}
        self._servers: list[asyncio.Server] = []
        self.lags: list[float] = []
        """How late each emission slot ran (seconds): is the generator keeping up?"""

    async def start(self, printers: int) -> None:
        """Bind one loopback port per printer and start serving."""
        loop = asyncio.get_running_loop()
        for index in range(printers):
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.bind(("127.0.0.1", 0))
            port = sock.getsockname()[1]
            endpoint = Endpoint(index, port)
            self.endpoints.append(endpoint)
            self.by_port[port] = endpoint
            server = await loop.create_server(lambda: Connection(self), sock=sock, backlog=256)
            self._servers.append(server)

    async def emit_forever(self) -> None:
        """Every 10 ms, one slot of printers sends its update: 4 Hz per printer."""
        period = 1.0 / UPDATES_PER_SECOND / SLOTS
        slots = [self.endpoints[slot::SLOTS] for slot in range(SLOTS)]
        due = time.monotonic()
        for slot in itertools.cycle(range(SLOTS)):
            due += period
            await asyncio.sleep(max(0.0, due - time.monotonic()))
            self.lags.append(time.monotonic() - due)
            for endpoint in slots[slot]:
                endpoint.emit()

    def dump(self, path: Path) -> None:
        """Write ``{"printers": [{port, base, sent_at}], "lags": [...]}`` as JSON."""
        printers = [
            {"port": e.port, "base": e.printer.base, "sent_at": e.sent_at.tolist()}
            for e in self.endpoints
        ]
        path.write_bytes(orjson.dumps({"printers": printers, "lags": self.lags}))

    def close(self) -> None:
        """Stop listening (open connections are dropped with the process)."""
        for server in self._servers:
            server.close()


async def _commands(generator: LoadGenerator) -> None:
    """Obey stdin until it ends."""
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    while line := (await reader.readline()).decode().strip():
        command, _, argument = line.partition(" ")
        if command == "dump":
            generator.dump(Path(argument))
        print(orjson.dumps({"done": command}).decode(), flush=True)


async def serve(printers: int, max_seconds: float) -> None:
    """Serve until stdin closes or ``max_seconds`` pass."""
    generator = LoadGenerator()
    await generator.start(printers)
    ports = [e.port for e in generator.endpoints]
    print(orjson.dumps({"banner": BANNER, "ports": ports}).decode(), flush=True)
    emitter = asyncio.create_task(generator.emit_forever())
    try:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(_commands(generator), max_seconds)
    finally:
        emitter.cancel()
        generator.close()


def main() -> None:
    """``python -m bench.loadgen --printers N``."""
    parser = argparse.ArgumentParser(description=BANNER)
    parser.add_argument("--printers", type=int, required=True)
    parser.add_argument("--max-seconds", type=float, default=1_800.0, help="stop by itself")
    args = parser.parse_args()
    print(f"{BANNER}: {args.printers} printers on 127.0.0.1", file=sys.stderr, flush=True)
    asyncio.run(serve(args.printers, args.max_seconds))


if __name__ == "__main__":
    main()
