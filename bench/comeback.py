"""How soon a restarted Moonraker is back in KyberCore: a real virtual printer (virtual MCU +
real Klippy + real Moonraker), its Moonraker stopped for 1 to 10 s, R times.

``python -m bench.comeback --restarts 30`` prints, per restart, the seconds from Moonraker
answering ``server.info`` with Klippy ready to KyberCore's session reporting Klippy ready
again, then the median, p95 and max; figures go to ``bench/results/comeback-<time>.json``.
:func:`comeback` is also what ``tests/moonraker/test_comeback.py`` runs (10 restarts).
"""

from __future__ import annotations

import argparse
import asyncio
import inspect
import random
import statistics
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, Final

import httpx
import orjson

from bench.fleet_scale import RESULTS_DIR

# kybercore ships no py.typed marker; mypy sees it as an untyped installed package.
from kybercore.moonraker.client import MoonrakerClient  # type: ignore[import-untyped, unused-ignore]
from kybercore.moonraker.events import KlippyChanged, SessionEvent  # type: ignore[import-untyped, unused-ignore]
from kybercore.moonraker.http import new_http_client  # type: ignore[import-untyped, unused-ignore]
from kybercore.sim.runtime import ensure_runtimes  # type: ignore[import-untyped, unused-ignore]
from kybercore.sim.stack import PrinterStack, StackOptions  # type: ignore[import-untyped, unused-ignore]

READY_WITHIN: Final = 60.0
"""Generous: Moonraker's own start-up takes 1-3 s on a busy 2-core machine."""
POLL: Final = 0.02


class Timed:
    """A session's events, each with the ``time.monotonic()`` it arrived at."""

    def __init__(self) -> None:
        self.events: list[tuple[float, SessionEvent]] = []

    def __call__(self, event: SessionEvent) -> None:
        self.events.append((time.monotonic(), event))

    def ready_at(self, mark: int) -> float | None:
        """When Klippy was last reported ready after event ``mark``, if it was."""
        found = None
        for at, event in self.events[mark:]:
            if isinstance(event, KlippyChanged):
                found = at if event.state == "ready" else None
        return found


async def until(predicate: Callable[[], bool | Awaitable[bool]], timeout: float, what: str) -> None:
    """Poll ``predicate`` (a function or a coroutine function) every 20 ms until it holds."""
    deadline = time.monotonic() + timeout
    while True:
        held = predicate()
        if inspect.isawaitable(held):
            held = await held
        if held:
            return
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(POLL)  # poll: deadline above


async def comeback(
    stack: PrinterStack, client: MoonrakerClient, timed: Timed, outage: float, back_within: float
) -> float:
    """Stop Moonraker for ``outage`` s, start it; seconds from its ready to the session's
    ready (0 when the session knew first). Raises if the session is not back within
    ``back_within`` s of Moonraker's ready."""
    mark = len(timed.events)
    stopped = time.monotonic()
    await asyncio.to_thread(stack.stop_moonraker)
    await until(lambda: client.session.connection == "offline", 10.0, "the session offline")
    # The outage itself: the measurement's input, not a wait for a condition.
    await asyncio.sleep(max(0.0, outage - (time.monotonic() - stopped)))
    await asyncio.to_thread(stack.start_moonraker)
    async with httpx.AsyncClient(trust_env=False, timeout=1.0) as probe:

        async def moonraker_ready() -> bool:
            try:
                info = (await probe.get(f"{stack.url}/server/info")).json()["result"]
            except (httpx.HTTPError, ValueError, KeyError):
                return False
            return bool(info["klippy_state"] == "ready")

        await until(moonraker_ready, READY_WITHIN, "Moonraker ready")
    ready = time.monotonic()
    await until(
        lambda: timed.ready_at(mark) is not None,
        back_within,
        f"the session ready again after an outage of {outage:g} s",
    )
    back = timed.ready_at(mark)
    assert back is not None
    return max(0.0, back - ready)


def summary(late: list[float]) -> dict[str, float]:
    """Median, p95 and max of the comeback times, in seconds."""
    ordered = sorted(late)
    p95 = ordered[round(0.95 * (len(ordered) - 1))]
    return {
        "median": round(statistics.median(ordered), 3),
        "p95": round(p95, 3),
        "max": round(ordered[-1], 3),
    }


async def run(restarts: int, seed: int) -> dict[str, Any]:
    """``restarts`` outages of 1-10 s (uniform, seeded) on one fresh virtual printer."""
    ensure_runtimes(log=lambda line: print(f"[runtimes] {line}"))
    outages = [round(random.Random(seed + n).uniform(1.0, 10.0), 2) for n in range(restarts)]
    with tempfile.TemporaryDirectory(prefix="kybercore-comeback-") as tmp:
        stack = PrinterStack(StackOptions(name="comeback", heat_rate=8.0), Path(tmp))
        stack.start()
        try:
            await asyncio.to_thread(stack.wait_ready)
            async with new_http_client() as http:
                timed = Timed()
                client = MoonrakerClient(stack.url, http, name="comeback", on_event=timed)
                client.start()
                try:
                    await until(lambda: timed.ready_at(0) is not None, 30.0, "the first ready")
                    late = []
                    for outage in outages:
                        late.append(await comeback(stack, client, timed, outage, READY_WITHIN))
                        print(f"outage {outage:5.2f} s: back {late[-1]:.2f} s after Moonraker")
                finally:
                    await client.close()
        finally:
            stack.stop()
    return {"outages_s": outages, "back_after_ready_s": late, **summary(late)}


def main() -> None:
    """``python -m bench.comeback --restarts R``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--restarts", type=int, default=30)
    parser.add_argument("--seed", type=int, default=15)
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = parser.parse_args()
    results = asyncio.run(run(args.restarts, args.seed))
    print(
        f"{args.restarts} Moonraker restarts (outages 1-10 s): back after Moonraker was ready "
        f"in median {results['median']} s, p95 {results['p95']} s, max {results['max']} s"
    )
    args.results_dir.mkdir(parents=True, exist_ok=True)
    path = args.results_dir / f"comeback-{int(time.time())}.json"
    path.write_bytes(orjson.dumps(results, option=orjson.OPT_INDENT_2))
    print(f"results: {path}")


if __name__ == "__main__":
    main()
