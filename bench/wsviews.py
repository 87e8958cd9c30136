"""Per-client cost of the ``/ws`` fan-out, in memory: the hub's publish plus what each
client's send costs, for M clients of an N-printer fleet.

``python -m bench.wsviews --printers 2000 --clients 50 --ticks 50 --page 24``

Each tick 40 % of the printers change (temperatures, ``updated_at``; printing ones also
progress and durations), as 4 updates/s per printer give a 100 ms tick. Three ways, one run:

- **text (before)**: every client shows every printer, and each frame is decoded to ``str``
  for ``send_text`` and encoded back to UTF-8 by the WebSocket library, per client;
- **binary, all**: every client shows every printer, the same bytes go to ``send_bytes``;
- **binary, pages**: every client shows its own page of ``--page`` printers (full views)
  and gets slim summaries of the rest.

No sockets: the kernel's copy is the same for every way and is not measured.
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from typing import Any

from kybercore.fleet.frames import DeltaFrames
from kybercore.fleet.hub import Hub, HubClient


def fleet_views(count: int) -> dict[str, dict[str, Any]]:
    """N views shaped like :func:`kybercore.core.view.fuse`'s, 60 % printing."""
    views = {}
    for i in range(count):
        busy = i % 5 < 3
        views[f"p{i:05d}"] = {
            "id": f"p{i:05d}",
            "name": f"Farm {i:05d}",
            "model": ("Voron 2.4", "Prusa MK4", "Ender 3")[i % 3],
            "location": f"Room {'ABCD'[i % 4]}",
            "power_group": "",
            "tags": ["farm", ("pla", "petg")[i % 2]],
            "notes": "",
            "moonraker_url": f"http://10.0.{i // 200}.{i % 200 + 10}:7125",
            "api_key_set": False,
            "enabled": True,
            "capabilities": {"build_volume": {"x": 250.0, "y": 210.0, "z": 220.0},
                             "nozzle_diameter": 0.4, "material": "PLA",
                             "max_extruder_temp": 290.0, "max_bed_temp": 120.0},
            "limits": "known",
            "connection": "online",
            "connection_error": "",
            "klippy_state": "ready",
            "klippy_message": "",
            "job": {"state": "printing" if busy else "standby",
                    "filename": f"part_{i % 17}.gcode" if busy else "",
                    "progress": 0.0, "eta_seconds": 3600 if busy else None,
                    "eta_at": 1.8e9 if busy else None, "estimated_time": 5400.0,
                    "print_duration": 0, "total_duration": 0, "message": "",
                    "layer": 1, "total_layers": 200, "thumbnail": None},
            "extruder": {"temperature": 210.0, "target": 210.0, "power": 0.5},
            "bed": {"temperature": 60.0, "target": 60.0, "power": 0.3},
            "toolhead": {"position": [10.0, 20.0, 1.0, 0.0], "homed_axes": "xyz"},
            "fan_speed": 1.0, "speed_factor": 1.0, "extrude_factor": 1.0, "z_offset": 0.0,
            "can_extrude": True, "spool": None,
            "actions": {"start": not busy, "pause": busy, "cancel": busy},
            "updated_at": 1.7e9,
        }  # fmt: skip
    return views


def step(views: dict[str, dict[str, Any]], rng: random.Random, now: float) -> list[str]:
    """Change 40 % of the printers as a tick's worth of Moonraker updates would."""
    changed = rng.sample(sorted(views), k=len(views) * 2 // 5)
    for printer_id in changed:
        old = views[printer_id]
        view = dict(old)  # views are replaced, never changed in place (the hub diffs them)
        view["extruder"] = {**old["extruder"], "temperature": 205 + rng.random() * 10}
        view["bed"] = {**old["bed"], "temperature": 59 + rng.random() * 2}
        view["updated_at"] = now
        if old["job"]["state"] == "printing":
            job = old["job"]
            view["job"] = {**job, "progress": round(job["progress"] + 0.0001, 4),
                           "print_duration": job["print_duration"] + 1,
                           "eta_seconds": job["eta_seconds"] - 1}  # fmt: skip
        views[printer_id] = view
    return changed


def run(mode: str, printers: int, clients: int, ticks: int, page: int) -> dict[str, float]:
    """One way, measured: ms per tick for the hub (rendering included), the fan-out alone
    (the frames of every client from the tick's patches, then their sends), bytes per
    client per tick."""
    rng = random.Random(7)
    views = fleet_views(printers)
    hub = Hub(lambda printer_id: views.get(printer_id))
    for printer_id in views:
        hub.mark(printer_id)
    hub.flush()
    connected: list[HubClient] = [hub.connect() for _ in range(clients)]
    ids = sorted(views)
    for n, client in enumerate(connected):
        if mode == "pages":
            start = (n * page) % max(1, printers - page)
            hub.watch(client, ids[start : start + page])
        drain(client)
    publish: list[float] = []
    fanout: list[float] = []
    sent = 0
    for tick in range(ticks):
        for printer_id in step(views, rng, 1.7e9 + tick):
            hub.mark(printer_id)
        # Render first (what flush would), to keep the tick's patches for the fan-out below.
        hub._render(hub._take_dirty())
        patches = dict(hub._unsent)
        started = time.perf_counter()
        hub.flush()
        publish.append(time.perf_counter() - started)
        for client in connected:
            sent += sum(len(frame) for frame in drain(client))
        # The fan-out alone, from the same patches: every client's frame, then its send.
        started = time.perf_counter()
        delta = DeltaFrames(tick, patches, [])
        for client in connected:
            frame = delta.frame(client.view)
            if mode == "text":
                # ws.py before: send_text(frame.decode()), and the library encodes it again.
                frame.decode().encode()
        fanout.append(time.perf_counter() - started)
    return {
        "hub_ms": statistics.median(publish) * 1000,
        "fanout_ms": statistics.median(fanout) * 1000,
        "per_client_us": statistics.median(fanout) / clients * 1e6,
        "kb_per_client_tick": sent / ticks / clients / 1000,
    }


def drain(client: HubClient) -> list[bytes]:
    """Take every queued frame, as the client's sender task would."""
    frames = []
    while not client.queue.empty():
        frames.append(client.queue.get_nowait())
    return frames


def main() -> None:
    """Run the three ways and print a table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--printers", type=int, default=2000)
    parser.add_argument("--clients", type=int, default=50)
    parser.add_argument("--ticks", type=int, default=50)
    parser.add_argument("--page", type=int, default=24)
    args = parser.parse_args()
    print(f"N = {args.printers} printers, M = {args.clients} clients, {args.ticks} ticks, "
          f"page = {args.page}")  # fmt: skip
    print("| way | hub publish / tick | fan-out / tick | per client / tick | kB / client / tick |")
    print("|---|---|---|---|---|")
    for mode, label in (("text", "text (before)"), ("all", "binary, all"),
                        ("pages", "binary, pages")):  # fmt: skip
        r = run(mode, args.printers, args.clients, args.ticks, args.page)
        print(f"| {label} | {r['hub_ms']:.2f} ms | {r['fanout_ms']:.2f} ms | "
              f"{r['per_client_us']:.0f} µs | {r['kb_per_client_tick']:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
