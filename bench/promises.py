"""The time promises the tests keep with slack, measured precisely, next to a same-run baseline.

``python -m bench.promises [--repeat N] [--no-production]`` measures, on loopback:

- against FAULT-INJECTION stand-ins (:mod:`tests.hardening.faulty_moonraker`, not Moonraker),
  one :class:`MoonrakerSession` each: a silent peer dropped by the keepalive, a stalled
  handshake given up, a call on a session that is not connected, the production keepalive
  and open timeouts, and the longest gap in a healthy printer's 20 Hz stream while a 50 MB
  frame recycles another session (baseline: the same stream with no faulty neighbour);
- the advisor cut at its 1.5 s budget by a peer that never answers (baseline: the budget);
- a real printer (virtual MCU + Klippy + Moonraker) behind a real ``kybercore serve``
  watched over ``/ws``: a status change reaching the browser, Moonraker stopped → shown
  offline, an action on it → 503, a pending call failing, and a SIGSTOPped Moonraker → 503
  (baseline: ``GET /api/health``, a request that touches no printer).

The tests assert these figures with at least 5x slack (see bench/README.md); this prints the
figures themselves. Each line: median and max over the runs, and the baseline of the same run.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import signal
import statistics
import tempfile
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
from pydantic import SecretStr
from tests.browser_mirror import BrowserMirror
from tests.hardening.faults import Recorder
from tests.hardening.faulty_moonraker import FaultyMoonraker
from tests.helpers import KyberCoreServer, wait_for

from kybercore.core.validation import PrinterFacts
from kybercore.errors import PrinterUnreachable
from kybercore.fleet.advisor import AdvisorConfig, advise
from kybercore.moonraker import session as moonraker_session
from kybercore.moonraker.backoff import Backoff
from kybercore.moonraker.client import FLEET_OBJECTS, MoonrakerClient, websocket_url
from kybercore.moonraker.session import MoonrakerSession
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.sim.runtime import ensure_runtimes
from kybercore.sim.stack import PrinterStack, StackOptions, free_port

Row = tuple[str, str, list[float], str]
"""(promise, the test constant that bounds it, measured seconds, baseline)."""
LONG_GCODE = {"script": "G4 P6000"}
PRINTER = "/api/printers/p"


def _ms(seconds: float) -> str:
    if seconds < 0.001:
        return f"{seconds * 1e6:.0f} µs"
    return f"{seconds * 1000:.1f} ms" if seconds < 1 else f"{seconds:.2f} s"


def _spread(values: list[float]) -> str:
    return f"median {_ms(statistics.median(values))}, max {_ms(max(values))}"


@contextlib.contextmanager
def _timeouts(ping_interval: float, ping_timeout: float, open_timeout: float) -> Iterator[None]:
    """The session's keepalive and open timeouts, as the tests' ``fast_timeouts`` sets them."""
    saved = (
        moonraker_session.PING_INTERVAL,
        moonraker_session.PING_TIMEOUT,
        moonraker_session.OPEN_TIMEOUT,
    )
    moonraker_session.PING_INTERVAL = ping_interval  # type: ignore[misc]
    moonraker_session.PING_TIMEOUT = ping_timeout  # type: ignore[misc]
    moonraker_session.OPEN_TIMEOUT = open_timeout  # type: ignore[misc]
    try:
        yield
    finally:
        (
            moonraker_session.PING_INTERVAL,  # type: ignore[misc]
            moonraker_session.PING_TIMEOUT,  # type: ignore[misc]
            moonraker_session.OPEN_TIMEOUT,  # type: ignore[misc]
        ) = saved


@contextlib.asynccontextmanager
async def _peer(scenario: str, **options: float) -> AsyncIterator[FaultyMoonraker]:
    standin = FaultyMoonraker(scenario, **options)  # type: ignore[arg-type]
    await standin.start()
    try:
        yield standin
    finally:
        await standin.stop()


@contextlib.asynccontextmanager
async def _session(
    url: str, name: str, backoff: Backoff | None = None
) -> AsyncIterator[tuple[MoonrakerSession, Recorder]]:
    rec = Recorder()
    session = MoonrakerSession(
        websocket_url(url),
        name=name,
        api_key=None,
        subscription=FLEET_OBJECTS,
        on_event=rec,
        client_name=f"kybercore-bench-{name}",
        version="bench",
        backoff=backoff or Backoff(base=0.1, cap=1.0),
    )
    session.start()
    try:
        yield session, rec
    finally:
        await session.stop()


async def _stream_gap(huge: bool) -> float:
    """Longest gap in a healthy stream while another session takes 3 frames of 50 MB (or,
    for the baseline, as long with no such neighbour)."""
    async with _peer("healthy") as healthy, _session(healthy.url, "healthy") as (_, rec):
        await wait_for(lambda: rec.snapshots() > 0, what="the healthy subscription")
        start = time.monotonic()
        if huge:
            async with (
                _peer("huge") as faulty,
                _session(faulty.url, "huge", Backoff(0.1, 0.5)) as (_, bad),
            ):
                await wait_for(lambda: len(bad.drops()) >= 3, timeout=30, what="3 recycles")
        else:
            await asyncio.sleep(1.5)  # the baseline window: as long as 3 recycles take
        return rec.max_gap(start, time.monotonic())


async def _silent_fast() -> float:
    """Fast keepalive (0.5 + 0.5 s): silence → the pending call fails."""
    with _timeouts(0.5, 0.5, 0.5):
        async with (
            _peer("silent", silent_after=4) as faulty,
            _session(faulty.url, "silent") as (session, _),
        ):
            await wait_for(lambda: bool(faulty.silenced_at), what="the peer to go silent")
            with contextlib.suppress(PrinterUnreachable):
                await session.call("printer.info")
            return time.monotonic() - faulty.silenced_at[0]


async def _stall_fast() -> tuple[float, float]:
    """Fast open timeout (0.5 s): start → first drop; then a call while not connected."""
    with _timeouts(0.5, 0.5, 0.5):
        async with _peer("stall") as faulty:
            start = time.monotonic()
            async with _session(faulty.url, "stall") as (session, rec):
                await wait_for(lambda: bool(rec.drops()), what="the open timeout")
                given_up = rec.drops()[0][0] - start
                before = time.monotonic()
                with contextlib.suppress(PrinterUnreachable):
                    await session.call("server.info")
                return given_up, time.monotonic() - before


async def _production() -> tuple[float, float]:
    """Production constants: silence → shown offline; stalled handshake → given up."""
    async with _peer("silent", silent_after=2) as silent, _peer("stall") as stall:
        start = time.monotonic()
        async with (
            _session(silent.url, "silent") as (_, silent_rec),
            _session(stall.url, "stall") as (_, stall_rec),
        ):
            await wait_for(lambda: bool(silent_rec.drops() and stall_rec.drops()), timeout=60)
            return (
                silent_rec.drops()[0][0] - silent.silenced_at[0],
                stall_rec.drops()[0][0] - start,
            )


async def _advisor_cut(http: httpx.AsyncClient) -> float:
    """A peer that accepts and never answers: how long the advisor is waited for."""

    peers: list[tuple[asyncio.StreamWriter, asyncio.Task[Any] | None]] = []

    async def never_answer(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peers.append((writer, asyncio.current_task()))
        await reader.read()  # stand-in: a peer that reads and never answers

    server = await asyncio.start_server(never_answer, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    cfg = AdvisorConfig(f"http://127.0.0.1:{port}/v1", SecretStr("bench"), budget_seconds=1.5)
    facts = PrinterFacts("online", "ready", "standby", "", (200.0, 200.0, 200.0), None, 0.4)
    try:
        before = time.monotonic()
        await advise(http, cfg, "start", facts, {"filename": "a.gcode"}, None)
        return time.monotonic() - before
    finally:
        for writer, _ in peers:
            writer.close()
        await asyncio.gather(*(task for _, task in peers if task), return_exceptions=True)
        server.close()
        await server.wait_closed()


async def _timed(call: Callable[[], Awaitable[Any]]) -> tuple[Any, float]:
    before = time.monotonic()
    result = await call()
    return result, time.monotonic() - before


async def _server_rows(repeat: int, work: Path) -> list[Row]:
    """A real printer behind a real ``kybercore serve``."""
    ensure_runtimes(log=lambda line: print(f"[runtimes] {line}"))
    stack = PrinterStack(StackOptions("promises", heat_rate=8.0), work / "printer")
    stack.start()
    server: KyberCoreServer | None = None
    try:
        stack.wait_ready()
        write_printers(
            work / "printers.json", [PrinterConfig(id="p", name="P", moonraker_url=stack.url)]
        )
        server = KyberCoreServer(work / "printers.json", free_port())
        server.start()
        server.wait_online(1)
        health, status, offline, offline_cmd, refused, pending = [], [], [], [], [], []
        async with (
            httpx.AsyncClient(base_url=server.url, timeout=60) as api,
            BrowserMirror(server.ws_url) as mirror,
            httpx.AsyncClient(timeout=30) as http,
        ):
            view = lambda: mirror.printers.get("p", {})  # noqa: E731
            for _ in range(20):
                health.append((await _timed(lambda: api.get("/api/health")))[1])
            for n in range(repeat):
                target = 40 + n
                await api.post("/api/printers/p/gcode", json={"script": f"M104 S{target}"})
                status.append(await mirror.wait(lambda t=target: view()["extruder"]["target"] == t))
                # A call in flight over the session when Moonraker goes away.
                client = MoonrakerClient(stack.url, http, name="p")
                client.start()
                await wait_for(lambda c=client: c.session.connection == "online")
                call = asyncio.ensure_future(client.call("printer.gcode.script", LONG_GCODE))
                failed_at: list[float] = []
                call.add_done_callback(lambda _, f=failed_at: f.append(time.monotonic()))
                await wait_for(lambda c=client: bool(c.session._pending), what="the call sent")
                before = time.monotonic()
                await asyncio.to_thread(stack.stop_moonraker)
                # As the test measures it: from Moonraker gone (its process exited)...
                offline.append(await mirror.wait(lambda: view()["connection"] == "offline"))
                # ...and from the stop command (Moonraker's own exit included).
                offline_cmd.append(time.monotonic() - before)
                with contextlib.suppress(PrinterUnreachable):
                    await call
                pending.append(failed_at[0] - before)
                await client.close()
                answer, took = await _timed(lambda: api.post("/api/printers/p/actions/home"))
                assert answer.status_code == 503, answer.text
                refused.append(took)
                await asyncio.to_thread(stack.start_moonraker)
                await mirror.wait(
                    lambda: view()["connection"] == "online" and view()["klippy_state"] == "ready",
                    timeout=60,
                )
            await api.post("/api/printers/p/gcode", json={"script": "M104 S0"})
            # Frozen: SIGSTOP while KyberCore still believes it online (the worst moment).
            os.kill(stack.pids["moonraker"], signal.SIGSTOP)
            try:
                frozen = [
                    (await _timed(lambda m=method, p=path: api.request(m, f"{PRINTER}/{p}")))[1]
                    for method, path in (("POST", "actions/home"), ("GET", "files"))
                ]
            finally:
                os.kill(stack.pids["moonraker"], signal.SIGCONT)
    finally:
        if server is not None:
            server.stop()
        stack.stop()
    base = f"GET /api/health {_spread(health)}"
    return [
        ("status change → /ws", "test_fleet_api LIVE_WITHIN", status, base),
        ("Moonraker exited → /ws offline", "test_fleet_api OFFLINE_WITHIN", offline, base),
        ("Moonraker stop command → /ws offline", "(context for the line above)", offline_cmd, base),
        ("action on an offline printer → 503", "test_fleet_api REFUSED_WITHIN", refused, base),
        ("stop command → pending call fails", "test_moonraker_session FAIL_WITHIN", pending, base),
        ("frozen Moonraker → 503", "test_timeouts FROZEN_ANSWER_WITHIN", frozen, base),
    ]


async def _main(repeat: int, production: bool, printer: bool) -> None:
    rows: list[Row] = []
    baseline = [await _stream_gap(huge=False) for _ in range(repeat)]
    gaps = [await _stream_gap(huge=True) for _ in range(repeat)]
    rows.append(
        ("healthy 20 Hz stream: longest gap while a 50 MB frame recycles a neighbour",
         "none (speed; test_upstream_faults)", gaps,
         f"no neighbour {_spread(baseline)}")
    )  # fmt: skip
    silent = [await _silent_fast() for _ in range(repeat)]
    rows.append(("silent peer → pending call fails (keepalive 0.5 + 0.5 s)",
                 "test_upstream_faults SILENT_FAST_WITHIN", silent,
                 "configured 1.0 s"))  # fmt: skip
    stalls = [await _stall_fast() for _ in range(repeat)]
    rows.append(("stalled handshake given up (open timeout 0.5 s)",
                 "test_upstream_faults STALL_FAST_WITHIN",
                 [s[0] for s in stalls], "configured 0.5 s"))  # fmt: skip
    rows.append(("call while not connected fails",
                 "none (it never suspends; test_upstream_faults)",
                 [s[1] for s in stalls], "—"))  # fmt: skip
    if production:
        silent_s, stall_s = await _production()
        rows.append(("production: silent peer shown offline",
                     "test_upstream_faults PRODUCTION_SILENCE_WITHIN",
                     [silent_s], "configured 5 + 5 s"))  # fmt: skip
        rows.append(("production: stalled handshake given up",
                     "test_upstream_faults PRODUCTION_STALL_WITHIN",
                     [stall_s], "configured 5 s"))  # fmt: skip
    async with httpx.AsyncClient(trust_env=False) as http:
        cuts = [await _advisor_cut(http) for _ in range(repeat)]
    rows.append(("advisor cut at its budget", "test_advisor CUT_WITHIN", cuts,
                 "budget 1.5 s"))  # fmt: skip
    if printer:
        with tempfile.TemporaryDirectory(prefix="kc-promises-") as work:
            rows += await _server_rows(repeat, Path(work))
    print(f"\nload average before/after: {_load_before} / {os.getloadavg()}")
    for promise, bound, values, base in rows:
        print(f"\n{promise}\n  measured: {_spread(values)} ({len(values)} runs)")
        print(f"  baseline: {base}\n  test bound: {bound}")


_load_before = os.getloadavg()

if __name__ == "__main__":
    logging.basicConfig(level=logging.ERROR)  # the faults' warnings are expected here
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs of each measurement")
    parser.add_argument("--no-production", action="store_true", help="skip the ~10 s timeouts")
    parser.add_argument("--no-printer", action="store_true", help="skip the real printer")
    args = parser.parse_args()
    asyncio.run(_main(args.repeat, not args.no_production, not args.no_printer))
