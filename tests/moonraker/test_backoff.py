"""Reconnect delays: exponential, jittered, capped, reset by a healthy connection; and quick,
steady retries while a printer that was just healthy refuses connections (a restart)."""

from __future__ import annotations

from kybercore.moonraker.backoff import Backoff


class Clock:
    """A hand-moved monotonic clock."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_delays_grow_to_the_cap_with_jitter_and_start_over_after_a_healthy_link() -> None:
    backoff = Backoff(base=0.5, cap=4.0, healthy_after=30.0)
    ceilings = [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    for ceiling in ceilings:
        delay = backoff.next_delay(connected_for=0.1)
        # Full jitter in the upper half: never zero, never over the ceiling.
        assert ceiling / 2 <= delay <= ceiling
    assert backoff.next_delay(connected_for=31.0) <= 0.5  # lasted long enough: news again
    backoff.next_delay(connected_for=0.1)
    backoff.healthy_session_ended(by_peer=True)
    assert backoff.next_delay(connected_for=0.1) <= 0.5


def test_refused_connections_soon_after_a_healthy_session_retry_every_1_to_1_5_s() -> None:
    clock = Clock()
    backoff = Backoff(base=0.5, cap=30.0, restart_window=300.0, clock=clock)
    backoff.healthy_session_ended(by_peer=True)  # Moonraker restarts
    for _ in range(40):  # a host rebooting: a minute of refusals, never a long wait
        delay = backoff.next_delay(connected_for=0.0, refused=True)
        assert 1.0 <= delay <= 1.5
        clock.now += delay
    # Past the window, a printer that keeps refusing backs off again, up to the cap.
    clock.now += 300.0
    delays = [backoff.next_delay(connected_for=0.0, refused=True) for _ in range(10)]
    assert max(delays) > 15.0


def test_timeouts_and_unreachable_hosts_keep_the_long_backoff() -> None:
    clock = Clock()
    backoff = Backoff(base=0.5, cap=30.0, clock=clock)
    backoff.healthy_session_ended(by_peer=False)
    delays = [backoff.next_delay(connected_for=0.0) for _ in range(8)]
    assert delays[-1] >= 15.0  # grew to the cap: a host that is off is not hammered
    # ...and when the host answers again, refusing (Moonraker still starting), quick again.
    assert 1.0 <= backoff.next_delay(connected_for=0.0, refused=True) <= 1.5


def test_refusals_without_a_healthy_session_before_back_off() -> None:
    """A wrong port (never healthy) is not retried every second forever."""
    backoff = Backoff(base=0.5, cap=30.0)
    delays = [backoff.next_delay(connected_for=0.0, refused=True) for _ in range(8)]
    assert delays[-1] >= 15.0
