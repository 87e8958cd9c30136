"""Small asyncio helpers shared by the long-lived tasks."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable, Hashable
from typing import Any, Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


async def cancel_and_wait(task: asyncio.Task[Any] | None) -> None:
    """Cancel a background task and wait until it has really finished.

    The task's own cancellation is expected and swallowed; the caller's is not: if the
    caller is cancelled while it waits, :class:`asyncio.CancelledError` propagates (the
    task, already cancelled, finishes on its own). An error the task ended with is raised.
    """
    if task is None:
        return
    task.cancel()
    # asyncio.wait, not `await task`: awaiting the task would turn the caller's cancellation
    # into the task's, and suppressing that would swallow the caller's.
    await asyncio.wait({task})
    if not task.cancelled():
        task.result()


class Remembered(Generic[K, V]):
    """Answers of an async lookup by key, each remembered for ``seconds``, with one lookup
    in flight per key however many callers ask at once (a slow key delays only its own
    callers). A lookup that fails is not remembered: the next call tries again."""

    def __init__(self, seconds: float) -> None:
        self._seconds = seconds
        self._known: dict[K, tuple[float, asyncio.Future[V]]] = {}

    async def get(self, key: K, look_up: Callable[[], Awaitable[V]]) -> V:
        """The remembered answer for ``key``, else ``look_up()``'s."""
        known = self._known.get(key)
        if known is None or time.monotonic() - known[0] >= self._seconds:
            future = asyncio.ensure_future(look_up())
            known = self._known[key] = (time.monotonic(), future)
            future.add_done_callback(lambda done: self._settled(key, done))
        # Shielded: one caller giving up must not cancel the lookup the others wait for.
        return await asyncio.shield(known[1])

    def _settled(self, key: K, done: asyncio.Future[V]) -> None:
        # Retrieved here, so an error nobody is left to await is not logged as lost.
        if done.cancelled() or done.exception() is not None:
            current = self._known.get(key)
            if current is not None and current[1] is done:
                del self._known[key]
