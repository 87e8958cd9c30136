"""Small asyncio helpers shared by the long-lived tasks."""

from __future__ import annotations

import asyncio
from typing import Any


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
