"""M browser clients of KyberCore's ``/ws``, in a process of their own.

Every client reads every frame, as a dashboard would, so KyberCore pays the full fan-out.
Only the first few *measuring* clients (``websockets``) parse the frames and note, per
printer, when each ``job.print_duration`` value arrived (see :mod:`bench.printer_model` for
why that value identifies the source update); the others are :class:`DrainClient` objects, which
read and drop: parsing 100 copies of the same frames would measure this process rather than
KyberCore.

With ``--views F`` (a JSON list of id lists, one per client), client i sends ``{"type":
"view", "printers": F[i]}`` right after its snapshot, as a dashboard showing a page of tiles
does: KyberCore then sends it full patches of those printers only and slim summaries of the
rest. A client counts as ready once a delta carries its ``full`` part (the view is in
effect), and a measuring client observes only those full patches: the slim summaries carry
no ``print_duration``.

With ``--deflate``, every client offers permessage-deflate as Chromium does (the benches
otherwise leave it out): KyberCore then compresses each frame once per client.

``python -m bench.browsers --url ws://127.0.0.1:PORT/ws --clients M --seconds S --out F``
prints ``{"ready": true, "connected": k}`` once every client has its snapshot (and its view
is in effect), then, after S
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


async def measure(
    url: str,
    tally: Tally,
    ready: asyncio.Future[None],
    view: list[str] | None = None,
    deflate: bool = False,
) -> None:
    """A measuring browser: snapshot first, then deltas until cancelled. With ``view``, it
    shows those printers: ready, and observing, once a delta carries their full patches."""
    seen: dict[str, list[Any]] = {"printer": [], "value": [], "t": []}
    tally.observations.append(seen)
    compression = "deflate" if deflate else None
    async with websockets.connect(url, compression=compression, max_size=None, proxy=None) as ws:
        await ws.recv(decode=False)  # the snapshot
        if view is None:
            ready.set_result(None)
        else:
            # A text frame: KyberCore reads the view with receive_json (text mode).
            await ws.send(orjson.dumps({"type": "view", "printers": view}).decode())
        while True:
            frame = await ws.recv(decode=False)
            received = time.monotonic()
            tally.frames += 1
            tally.bytes += len(frame)
            message = orjson.loads(frame)
            kind = message.get("type")
            if kind == "snapshot":
                tally.resyncs += 1  # overflowed: KyberCore replaced the backlog
            elif kind == "delta" and view is None:
                _observe(message["printers"], received, seen)
            elif kind == "delta" and "full" in message:
                if not ready.done():
                    ready.set_result(None)
                _observe(message["full"], received, seen)
            # A delta without "full" while showing a view was sent before KyberCore applied
            # the view (every printer in full): not the regime being measured.


def _observe(patches: dict[str, Any], received: float, seen: dict[str, list[Any]]) -> None:
    for printer_id, patch in patches.items():
        duration = (patch.get("job") or {}).get("print_duration")
        if duration is not None:
            seen["printer"].append(printer_id)
            seen["value"].append(duration)
            seen["t"].append(received)


async def run(
    url: str,
    clients: int,
    seconds: float,
    connect_timeout: float,
    views: list[list[str]] | None = None,
    deflate: bool = False,
) -> dict[str, Any]:
    """Connect ``clients`` browsers, say so, then listen for ``seconds``. ``views``: the
    printers each client shows (None: every client gets the whole fleet in full);
    ``deflate``: the clients offer permessage-deflate."""
    loop = asyncio.get_running_loop()
    tally = Tally()
    measuring = min(clients, MEASURING_CLIENTS)
    ready = [loop.create_future() for _ in range(clients)]
    shown: list[list[str] | None] = list(views) if views is not None else [None] * clients
    tasks = [
        asyncio.create_task(measure(url, tally, ready[i], shown[i], deflate))
        for i in range(measuring)
    ]
    parts = urlsplit(url)
    host, port = parts.hostname or "127.0.0.1", parts.port or 80
    drains: list[DrainClient] = []
    for future, view in zip(ready[measuring:], shown[measuring:], strict=True):
        factory = functools.partial(DrainClient, host, port, future, view, deflate)
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
    parser.add_argument(
        "--views", type=Path, help="JSON list of the printer ids each client shows, in order"
    )
    parser.add_argument("--deflate", action="store_true", help="offer permessage-deflate")
    args = parser.parse_args()
    views = orjson.loads(args.views.read_bytes()) if args.views else None
    if views is not None and len(views) != args.clients:
        parser.error(f"--views lists {len(views)} views for {args.clients} clients")
    result = asyncio.run(
        run(args.url, args.clients, args.seconds, args.connect_timeout, views, args.deflate)
    )
    args.out.write_bytes(orjson.dumps(result))


if __name__ == "__main__":
    main()
