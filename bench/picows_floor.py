"""The floor of ingest: a bare ``picows`` + ``orjson`` consumer of the same N Moonraker streams.

The same WebSocket library and JSON decoder KyberCore uses, on uvloop when it is installed
(as ``kybercore serve`` runs), and nothing else: per frame one ``orjson.loads`` and a count.
What KyberCore spends per event beyond this is its own work (state, views, listeners,
browsers); what this spends is the receive path no consumer avoids.

``python -m bench.picows_floor --ports-file F --seconds S`` prints one JSON line:
``{"events", "seconds", "cpu_seconds", "cpu_per_1000", "connected"}``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import time
from pathlib import Path
from typing import Final

import orjson
from picows import WSFrame, WSListener, WSMsgType, WSTransport, ws_connect

# kybercore ships no py.typed marker; mypy sees it as an untyped installed package.
from kybercore.moonraker.client import FLEET_OBJECTS  # type: ignore[import-untyped, unused-ignore]

CONNECT_CONCURRENCY: Final = 200
_STATUS: Final = "notify_status_update"


class Counter:
    """Status updates received while the window is open."""

    def __init__(self) -> None:
        self.events = 0
        self.counting = False


class FloorListener(WSListener):
    """Subscribes on connect, then decodes every frame and counts the status updates."""

    def __init__(self, counter: Counter) -> None:
        super().__init__()
        self._counter = counter

    def on_ws_connected(self, transport: WSTransport) -> None:
        # Moonraker answers in order; nothing here needs the answers, only the stream.
        subscribe = {"objects": dict(FLEET_OBJECTS)}
        for req_id, method, params in (
            (1, "server.connection.identify", {"client_name": "floor", "version": "0"}),
            (2, "printer.objects.subscribe", subscribe),
        ):
            request = {"jsonrpc": "2.0", "id": req_id, "method": method, "params": params}
            transport.send(WSMsgType.TEXT, orjson.dumps(request))

    def on_ws_frame(self, transport: WSTransport, frame: WSFrame) -> None:
        if frame.msg_type != WSMsgType.TEXT:
            return
        message = orjson.loads(frame.get_payload_as_memoryview())
        if self._counter.counting and message.get("method") == _STATUS:
            self._counter.events += 1


async def run(ports: list[int], seconds: float, settle: float) -> dict[str, float]:
    """Connect to every port, let the streams settle, then count for ``seconds``."""
    counter = Counter()
    gate = asyncio.Semaphore(CONNECT_CONCURRENCY)
    transports: list[WSTransport] = []

    async def connect(port: int) -> None:
        async with gate:
            url = f"ws://127.0.0.1:{port}/websocket"
            transport, _ = await ws_connect(lambda: FloorListener(counter), url)
            transports.append(transport)

    await asyncio.gather(*(connect(port) for port in ports))
    await asyncio.sleep(settle)
    cpu, started = time.process_time(), time.monotonic()
    counter.counting = True
    await asyncio.sleep(seconds)
    counter.counting = False
    elapsed, cpu = time.monotonic() - started, time.process_time() - cpu
    for transport in transports:
        transport.disconnect()
    return {
        "events": counter.events,
        "seconds": elapsed,
        "cpu_seconds": cpu,
        "cpu_per_1000": cpu / max(counter.events, 1) * 1000,
        "connected": len(transports),
    }


def main() -> None:
    """``python -m bench.picows_floor --ports-file F --seconds S``."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--ports-file", type=Path, required=True, help="JSON list of ports")
    parser.add_argument("--seconds", type=float, required=True)
    parser.add_argument("--settle", type=float, default=3.0)
    args = parser.parse_args()
    ports = orjson.loads(args.ports_file.read_bytes())
    with contextlib.suppress(ImportError):
        import uvloop  # as kybercore serve (uvicorn) runs

        asyncio.set_event_loop_policy(uvloop.EventLoopPolicy())
    result = asyncio.run(run(ports, args.seconds, args.settle))
    print(orjson.dumps(result).decode(), flush=True)


if __name__ == "__main__":
    main()
