"""Helpers shared by the upstream-fault tests: event recording and stand-ins in a process."""

from __future__ import annotations

import contextlib
import itertools
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from kybercore.moonraker.events import ConnectionChanged, SessionEvent, StatusDelta, StatusSnapshot

ROOT = Path(__file__).resolve().parents[2]


class Recorder:
    """A session's events, each with the ``time.monotonic()`` it arrived at."""

    def __init__(self) -> None:
        self.events: list[tuple[float, SessionEvent]] = []

    def __call__(self, event: SessionEvent) -> None:
        self.events.append((time.monotonic(), event))

    def of(self, kind: type[SessionEvent]) -> list[SessionEvent]:
        return [e for _, e in self.events if isinstance(e, kind)]

    def connections(self) -> list[str]:
        return [e.connection for _, e in self.events if isinstance(e, ConnectionChanged)]

    def drops(self) -> list[tuple[float, str]]:
        """(time, reason) of every time the session went offline."""
        return [
            (at, e.detail)
            for at, e in self.events
            if isinstance(e, ConnectionChanged) and e.connection == "offline"
        ]

    def snapshots(self) -> int:
        return len(self.of(StatusSnapshot))

    def good_deltas(self) -> list[tuple[float, float]]:
        """(time, temperature) of the stand-in's own deltas (temperatures from 20 up)."""
        out = []
        for at, e in self.events:
            if isinstance(e, StatusDelta):
                temperature = e.delta.get("extruder", {}).get("temperature")
                if isinstance(temperature, float) and temperature >= 20.0:
                    out.append((at, temperature))
        return out

    def max_gap(self, start: float, end: float) -> float:
        """The longest time without a delta between ``start`` and ``end``."""
        times = [start, *(at for at, _ in self.good_deltas() if start < at < end), end]
        return max(b - a for a, b in itertools.pairwise(times))


class StandinProcess:
    """A FaultyMoonraker in a process of its own (its memory stays out of measurements)."""

    def __init__(self, scenario: str) -> None:
        self.scenario = scenario
        self.connections = 0
        self.huge_frames_sent = 0
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "tests.hardening.faulty_moonraker", scenario],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self._proc.stdout is not None
        first = self._proc.stdout.readline().split()
        assert first[:1] == ["PORT"], f"the stand-in did not start: {first}"
        self.url = f"http://127.0.0.1:{first[1]}"
        self._reader = threading.Thread(target=self._follow, daemon=True)
        self._reader.start()

    def _follow(self) -> None:
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            parts = line.split()
            if parts[:1] == ["CONNECTIONS"]:
                self.connections, self.huge_frames_sent = int(parts[1]), int(parts[3])

    def stop(self) -> None:
        self._proc.kill()
        self._proc.wait()


@contextlib.contextmanager
def standin_process(scenario: str) -> Iterator[StandinProcess]:
    """Run a stand-in in its own process for the duration of a ``with`` block."""
    standin = StandinProcess(scenario)
    try:
        yield standin
    finally:
        standin.stop()


def rss_bytes(pid: int | str = "self") -> int:
    """Resident memory of a process, from /proc."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no VmRSS for {pid}")


class RssSampler:
    """The highest resident memory of a process while a ``with`` block runs (20 ms samples)."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.before = self.peak = rss_bytes(pid)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._stop.wait(0.02):
            self.peak = max(self.peak, rss_bytes(self.pid))

    @property
    def growth(self) -> int:
        return self.peak - self.before

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join()
