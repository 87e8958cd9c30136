"""Faults a real Moonraker cannot produce on demand, against :class:`MoonrakerSession`.

Every peer here is the FAULT-INJECTION stand-in of :mod:`tests.hardening.faulty_moonraker`.
Junk must be ignored without dropping the link; a 50 MB frame, a silent peer and a stalled
handshake must make the session recycle (drop, fail pending calls, reconnect) within its
timeouts; a healthy printer served by the same event loop must not notice; memory must stay
bounded. Most tests shorten the keepalive and open timeouts (module constants) to keep the
suite fast; one runs the production values.
"""

from __future__ import annotations

import itertools
import time
import tracemalloc
from collections.abc import AsyncIterator, Callable

import pytest

from kybercore.errors import MoonrakerRpcError, PrinterUnreachable
from kybercore.moonraker import session as moonraker_session
from kybercore.moonraker.backoff import Backoff
from kybercore.moonraker.client import FLEET_OBJECTS, websocket_url
from kybercore.moonraker.events import StatusDelta
from kybercore.moonraker.session import MoonrakerSession
from tests.hardening.conftest import FAST_OPEN_TIMEOUT, StartStandin
from tests.hardening.faults import Recorder, rss_bytes, standin_process
from tests.hardening.faulty_moonraker import (
    BAD_SHAPES,
    MALFORMED,
    UNKNOWN,
    FaultyMoonraker,
)
from tests.helpers import wait_for

pytestmark = pytest.mark.timeout(120)

# Promises, each bounded with at least 5x slack over its figure on an idle machine; the
# mechanism is checked exactly (the reason of the drop), and `python -m bench.promises`
# measures the figures themselves (see bench/README.md).
SILENT_FAST_WITHIN = 5.0
"""Fast keepalive (0.5 + 0.5 s): silence -> the pending call fails. Idle: 0.96 s."""
STALL_FAST_WITHIN = 2.5
"""Fast open timeout (0.5 s): the session starts -> its first drop. Idle: 0.50 s."""
PRODUCTION_SILENCE_WITHIN = 50.0
"""Production keepalive: silence -> shown offline. Idle: 9.96 s (the configured 5 + 5 s)."""
PRODUCTION_STALL_WITHIN = 25.0
"""Production open timeout: the session starts -> it gives up. Idle: 5.00 s (configured 5 s)."""

OpenSession = Callable[..., tuple[MoonrakerSession, Recorder]]


@pytest.fixture
async def sessions() -> AsyncIterator[OpenSession]:
    opened: list[MoonrakerSession] = []

    def open_session(
        url: str, name: str = "printer", backoff: Backoff | None = None
    ) -> tuple[MoonrakerSession, Recorder]:
        recorder = Recorder()
        session = MoonrakerSession(
            websocket_url(url),
            name=name,
            api_key=None,
            subscription=FLEET_OBJECTS,
            on_event=recorder,
            client_name=f"kybercore-hardening-{name}",
            version="test",
            backoff=backoff or Backoff(base=0.1, cap=1.0),
        )
        session.start()
        opened.append(session)
        return session, recorder

    yield open_session
    for session in opened:
        await session.stop()


async def healthy_pair(
    standins: StartStandin, sessions: OpenSession
) -> tuple[FaultyMoonraker, MoonrakerSession, Recorder]:
    healthy = await standins("healthy")
    session, rec = sessions(healthy.url, "healthy")
    await wait_for(lambda: rec.snapshots() > 0, what="the healthy printer's subscription")
    return healthy, session, rec


async def healthy_keeps_flowing(
    healthy: FaultyMoonraker, session: MoonrakerSession, rec: Recorder
) -> None:
    """The healthy printer next to a fault never dropped, and its stream still flows."""
    assert healthy.connections == 1
    assert rec.connections() == ["online"]
    assert session.connection == "online"
    seen = len(rec.good_deltas())
    await wait_for(lambda: len(rec.good_deltas()) >= seen + 3, what="the healthy stream")


# -- junk is ignored ---------------------------------------------------------------------

JUNK = {"malformed": MALFORMED, "unknown": UNKNOWN, "bad_shapes": BAD_SHAPES}


@pytest.mark.parametrize("scenario", sorted(JUNK))
async def test_junk_frames_are_ignored_without_dropping_the_session(
    scenario: str, standins: StartStandin, sessions: OpenSession
) -> None:
    faulty = await standins(scenario)
    session, rec = sessions(faulty.url, scenario)
    # The stand-in sends one junk frame before each good delta: go through the list twice.
    wanted = 2 * len(JUNK[scenario]) + 5
    await wait_for(
        lambda: len(rec.good_deltas()) >= wanted, timeout=15, what=f"{wanted} good deltas"
    )
    assert faulty.connections == 1, "junk must not cost the connection"
    assert rec.connections() == ["online"]
    assert session.connection == "online"
    assert session.klippy_state == "ready"
    # Consumers only ever see printer objects that are objects.
    for delta in rec.of(StatusDelta):
        assert isinstance(delta, StatusDelta)
        assert all(isinstance(fields, dict) for fields in delta.delta.values()), delta
    # Calls still get their answers between the junk.
    assert (await session.call("printer.info"))["state"] == "ready"
    if scenario == "bad_shapes":
        # An error whose code is not a number is still a typed error, not a dead reader.
        with pytest.raises(MoonrakerRpcError) as error:
            await session.call("printer.gcode.script", {"script": "G28"})
        assert error.value.rpc_code == -1
        # The reader went on past that error: more good deltas, and calls still answered.
        seen = len(rec.good_deltas())
        await wait_for(
            lambda: len(rec.good_deltas()) >= seen + 3, what="good deltas after the bad error"
        )
        assert (await session.call("printer.info"))["state"] == "ready"
        assert session.running
        assert session.connection == "online"
        assert faulty.connections == 1


async def test_a_malformed_answer_recycles_the_session_with_growing_backoff(
    standins: StartStandin, sessions: OpenSession
) -> None:
    faulty = await standins("bad_info")  # server.info answers a list
    backoff = Backoff(base=0.1, cap=0.8)
    session, rec = sessions(faulty.url, "bad-info", backoff)
    # It keeps trying...
    await wait_for(lambda: faulty.connections >= 6, what="six attempts")
    assert session.running, "the session task died on an answer it did not expect"
    drops = rec.drops()
    assert drops
    assert "unexpected answer to 'server.info'" in drops[-1][1]
    # ...but backs off: attempt n + 1 comes at least half of min(cap, base * 2**n) after
    # attempt n (0.05 s, 0.1, 0.2, then 0.4 s at the cap), never 60 tries in 3 s. Lower
    # bounds only: a busy machine makes the gaps longer, never shorter.
    gaps = [b - a for a, b in itertools.pairwise(faulty.connected_at[:6])]
    for n, gap in enumerate(gaps):
        assert gap >= min(backoff.cap, backoff.base * 2**n) / 2, (n, gaps)
    # Between attempts, calls fail at once with the reason. On a busy machine the next
    # attempt may open the socket between the check and the call (the call then reaches
    # the stand-in): wait for the next offline moment and call again.
    for _ in range(20):
        await wait_for(lambda: session.connection == "offline", what="an offline moment")
        try:
            await session.call("server.info")
        except PrinterUnreachable as exc:
            if "unexpected answer" in str(exc):
                break
    else:
        pytest.fail("no call between attempts failed with the reason")


# -- recycling: huge frame, silence, stalled handshake -------------------------------------


async def test_a_50mb_frame_recycles_the_session_and_others_keep_flowing(
    standins: StartStandin, sessions: OpenSession
) -> None:
    healthy, healthy_session, healthy_rec = await healthy_pair(standins, sessions)
    faulty = await standins("huge")
    start = time.monotonic()
    session, rec = sessions(faulty.url, "huge", Backoff(base=0.1, cap=0.5))
    await wait_for(lambda: len(rec.drops()) >= 3, timeout=15, what="three recycles")
    end = time.monotonic()
    assert all("message too big" in why for _, why in rec.drops()), rec.drops()
    assert faulty.connections >= 3
    assert rec.snapshots() >= 3, "each new connection subscribes again"
    assert session.running
    # The other printer on the same event loop did not notice: never dropped, still flowing.
    # (How steadily it flowed is a benchmark: bench/promises.py measures the longest gap.)
    print(f"\nthe healthy stream's longest gap: {healthy_rec.max_gap(start, end):.2f} s")
    await healthy_keeps_flowing(healthy, healthy_session, healthy_rec)


async def test_a_silent_peer_is_dropped_within_the_keepalive_and_pending_calls_fail(
    fast_timeouts: None, standins: StartStandin, sessions: OpenSession
) -> None:
    healthy, healthy_session, healthy_rec = await healthy_pair(standins, sessions)
    faulty = await standins("silent", silent_after=4)
    session, rec = sessions(faulty.url, "silent")
    await wait_for(lambda: bool(faulty.silenced_at), what="the peer to go silent")
    silent_since = faulty.silenced_at[0]
    # A call sent now is never read: it must fail when the session drops, not hang.
    with pytest.raises(PrinterUnreachable) as error:
        await session.call("printer.info")
    failed_after = time.monotonic() - silent_since
    assert "keepalive ping timeout" in error.value.message
    assert failed_after < SILENT_FAST_WITHIN, f"noticed the silence after {failed_after:.1f} s"
    assert rec.drops()[0][0] - silent_since < SILENT_FAST_WITHIN
    # ...and it recycles: a new connection, a new subscription.
    await wait_for(lambda: faulty.connections >= 2 and rec.snapshots() >= 2, what="a reconnect")
    await healthy_keeps_flowing(healthy, healthy_session, healthy_rec)


async def test_a_stalled_handshake_times_out_and_keeps_retrying(
    fast_timeouts: None, standins: StartStandin, sessions: OpenSession
) -> None:
    healthy, healthy_session, healthy_rec = await healthy_pair(standins, sessions)
    faulty = await standins("stall")
    start = time.monotonic()
    session, rec = sessions(faulty.url, "stall")
    await wait_for(lambda: bool(rec.drops()), timeout=10, what="the open timeout")
    assert rec.drops()[0][1].startswith("timed out while connecting")
    assert FAST_OPEN_TIMEOUT <= rec.drops()[0][0] - start < STALL_FAST_WITHIN
    # Calls fail at once while the session cannot connect: the call raises on its first
    # step, never suspending, so nothing can wait on the stall (bench/promises.py: ~20 µs).
    call = session.call("server.info")
    try:
        with pytest.raises(PrinterUnreachable):
            call.send(None)
    finally:
        call.close()
    await wait_for(lambda: faulty.connections >= 3, timeout=10, what="three attempts")
    assert session.running
    await healthy_keeps_flowing(healthy, healthy_session, healthy_rec)


async def test_production_timeouts_notice_silent_and_stalled_peers_within_11_s(
    standins: StartStandin, sessions: OpenSession
) -> None:
    """The real constants, not the test ones: both faults are noticed in bounded time."""
    silent = await standins("silent", silent_after=2)
    stall = await standins("stall")
    start = time.monotonic()
    _, silent_rec = sessions(silent.url, "silent")
    _, stall_rec = sessions(stall.url, "stall")
    await wait_for(
        lambda: bool(silent_rec.drops()), timeout=PRODUCTION_SILENCE_WITHIN + 10, what="silence"
    )
    noticed = silent_rec.drops()[0][0] - silent.silenced_at[0]
    assert "keepalive ping timeout" in silent_rec.drops()[0][1]
    assert noticed < PRODUCTION_SILENCE_WITHIN, (
        f"a silent printer looked online for {noticed:.1f} s"
    )
    await wait_for(
        lambda: bool(stall_rec.drops()), timeout=PRODUCTION_STALL_WITHIN, what="the stall given up"
    )
    assert stall_rec.drops()[0][1].startswith("timed out while connecting")
    assert stall_rec.drops()[0][0] - start < PRODUCTION_STALL_WITHIN
    # The promises are these constants: silence noticed within 11 s (a ping after 5 s of
    # silence, 5 s for its pong, 1 s for the close), a stalled handshake given up after 5 s.
    ping_total = moonraker_session.PING_INTERVAL + moonraker_session.PING_TIMEOUT
    assert ping_total + moonraker_session.CLOSE_TIMEOUT <= 11
    assert moonraker_session.OPEN_TIMEOUT <= 5


# -- memory ------------------------------------------------------------------------------

HUGE_FRAMES = 6
MAX_TRACED_GROWTH = 16 * 1024 * 1024
MAX_RSS_GROWTH = 64 * 1024 * 1024


async def test_memory_stays_bounded_through_many_50mb_frames(sessions: OpenSession) -> None:
    """The stand-in runs in its own process: only KyberCore's side is measured."""
    with standin_process("huge") as faulty:
        rss_before = rss_bytes()
        tracemalloc.start()
        try:
            traced_before, _ = tracemalloc.get_traced_memory()
            tracemalloc.reset_peak()
            _, rec = sessions(faulty.url, "huge", Backoff(base=0.05, cap=0.2))
            await wait_for(
                lambda: len(rec.drops()) >= HUGE_FRAMES,
                timeout=60,
                what=f"{HUGE_FRAMES} frames of 50 MB",
            )
            _, traced_peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        rss_after = rss_bytes()
        # The stand-in reports its count every 50 ms: a drop can be quicker than that.
        await wait_for(
            lambda: faulty.huge_frames_sent >= HUGE_FRAMES, timeout=2, what="the stand-in's count"
        )
    assert all("message too big" in why for _, why in rec.drops())
    print(
        f"\n{len(rec.drops())} frames of 50 MB: Python allocations peaked "
        f"{(traced_peak - traced_before) / 2**20:.1f} MiB above the start; RSS "
        f"{rss_before / 2**20:.0f} -> {rss_after / 2**20:.0f} MiB"
    )
    assert traced_peak - traced_before < MAX_TRACED_GROWTH
    assert rss_after - rss_before < MAX_RSS_GROWTH
