"""M browser clients of KyberCore's ``/ws``, in a process of their own.

Every client reads every frame, as a dashboard would, so KyberCore pays the full fan-out.
Only the first few *measuring* clients (``websockets``) parse the frames and note, per
printer, when each ``job.print_duration`` value arrived (see :mod:`bench.printer_model` for
why that value identifies the source update); the others are :class:`DrainClient` objects, which
read and drop: parsing 100 copies of the same frames would measure this process rather than
KyberCore.

``python -m bench.browsers --url ws://127.0.0.1:PORT/ws --clients M --seconds S --out F``
prints ``{"ready": true, "connected": k}`` once every client has its snapshot, then, after S
seconds, writes F: ``{"frames", "bytes", "resyncs", "cpu_seconds", "observations":
[{"printer", "value", "t"}]}``, one observation list per measuring client: printer id,
print duration, monotonic time of arrival.
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final
from urllib.parse import urlsplit

import orjson
import websockets

from bench.drain import DrainClient

MEASURING_CLIENTS: Final = 2


@dataclass
class Tally:
    """What the measuring clients received and observed."""

    frames: int = 0
    bytes: int = 0
    resyncs: int = 0
    observations: list[dict[str, list[Any]]] = field(default_factory=list)


async def measure(url: str, tally: Tally, ready: asyncio.Future[None]) -> None:
    """A measuring browser: snapshot first, then deltas until cancelled."""
    seen: dict[str, list[Any]] = {"printer": [], "value": [], "t": []}
    tally.observations.append(seen)
    async with websockets.connect(url, compression=None, max_size=None, proxy=None) as ws:
        await ws.recv(decode=False)  # the snapshot
        ready.set_result(None)
        while True:
            frame = await ws.recv(decode=False)
            received = time.monotonic()
            tally.frames += 1
            tally.bytes += len(frame)
            message = orjson.loads(frame)
            if message.get("type") == "snapshot":
                tally.resyncs += 1  # overflowed: KyberCore replaced the backlog
            elif message.get("type") == "delta":
                _observe(message, received, seen)


def _observe(delta: dict[str, Any], received: float, seen: dict[str, list[Any]]) -> None:
    for printer_id, patch in delta["printers"].items():
        duration = (patch.get("job") or {}).get("print_duration")
        if duration is not None:
            seen["printer"].append(printer_id)
            seen["value"].append(duration)
            seen["t"].append(received)


async def run(url: str, clients: int, seconds: float, connect_timeout: float) -> dict[str, Any]:
    """Connect ``clients`` browsers, say so, then listen for ``seconds``."""
    loop = asyncio.get_running_loop()
    tally = Tally()
    measuring = min(clients, MEASURING_CLIENTS)
    ready = [loop.create_future() for _ in range(clients)]
    tasks = [asyncio.create_task(measure(url, tally, ready[i])) for i in range(measuring)]
    parts = urlsplit(url)
    host, port = parts.hostname or "127.0.0.1", parts.port or 80
    drains: list[DrainClient] = []
    for future in ready[measuring:]:
        factory = functools.partial(DrainClient, host, port, future)
        _, drain = await loop.create_connection(factory, host, port)
        drains.append(drain)
    done, _ = await asyncio.wait(ready, timeout=connect_timeout)
    connected = sum(not f.exception() for f in done)
    print(orjson.dumps({"ready": True, "connected": connected}).decode(), flush=True)
    cpu = time.process_time()
    await asyncio.sleep(seconds)
    cpu = time.process_time() - cpu
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    for drain in drains:
        drain.close()
    return {
        "frames": tally.frames + sum(d.frames for d in drains),
        "bytes": tally.bytes + sum(d.bytes for d in drains),
        # Each drain client's first snapshot is its initial one, not a resync.
        "resyncs": tally.resyncs + sum(max(d.snapshots - 1, 0) for d in drains),
        "observations": tally.observations,
        "cpu_seconds": cpu,
    }


def main() -> None:
    """``python -m bench.browsers``."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--url", required=True)
    parser.add_argument("--clients", type=int, required=True)
    parser.add_argument("--seconds", type=float, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--connect-timeout", type=float, default=60.0)
    args = parser.parse_args()
    result = asyncio.run(run(args.url, args.clients, args.seconds, args.connect_timeout))
    args.out.write_bytes(orjson.dumps(result))


if __name__ == "__main__":
    main()
