"""A front cut off from the broker tells the browsers once when it happens and once when it
ends, and a browser connecting meanwhile learns it (:mod:`kybercore.scale.cut_off`)."""

from __future__ import annotations

from typing import Any

from kybercore.scale.cut_off import CutOff


def test_each_change_is_told_once_and_a_late_browser_gets_the_frame() -> None:
    told: list[dict[str, Any]] = []
    cut_off = CutOff(told.append)
    cut_off.follow(True)
    assert told == []
    assert cut_off.frame() is None
    cut_off.follow(False)
    cut_off.follow(False)  # checked 4 times a second: still one event
    assert len(told) == 1
    assert told[0]["type"] == "broker"
    assert told[0]["connected"] is False
    assert cut_off.frame() == told[0]  # what a browser connecting now gets
    cut_off.follow(True)
    assert told[1:] == [{"type": "broker", "connected": True}]
    assert cut_off.frame() is None
