"""Reconnect delays: exponential, jittered, capped, and reset by a healthy connection."""

from __future__ import annotations

from kybercore.moonraker.backoff import Backoff


def test_delays_grow_to_the_cap_with_jitter_and_start_over_after_a_healthy_link() -> None:
    backoff = Backoff(base=0.5, cap=4.0, healthy_after=30.0)
    ceilings = [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    for ceiling in ceilings:
        delay = backoff.next_delay(connected_for=0.1)
        # Full jitter in the upper half: never zero, never over the ceiling.
        assert ceiling / 2 <= delay <= ceiling
    assert backoff.next_delay(connected_for=31.0) <= 0.5  # lasted long enough: news again
    backoff.next_delay(connected_for=0.1)
    backoff.reset()
    assert backoff.next_delay(connected_for=0.1) <= 0.5
