"""``cancel_and_wait``: it waits for the task it cancels, and never eats its caller's own
cancellation."""

from __future__ import annotations

import asyncio

import pytest

from kybercore.aio import cancel_and_wait


async def slow_to_stop(stopping: asyncio.Event, release: asyncio.Event) -> None:
    """A task that, once cancelled, needs ``release`` before it really ends (a session
    saying goodbye to Moonraker, say)."""
    try:
        await asyncio.Event().wait()
    except asyncio.CancelledError:
        stopping.set()
        await release.wait()
        raise


async def test_waits_until_the_task_has_finished() -> None:
    stopping, release = asyncio.Event(), asyncio.Event()
    task = asyncio.create_task(slow_to_stop(stopping, release))
    await asyncio.sleep(0)  # let the task start, so cancelling it reaches its except clause
    waiter = asyncio.create_task(cancel_and_wait(task))
    await stopping.wait()
    assert not waiter.done()
    release.set()
    await waiter
    assert task.cancelled()


async def test_the_callers_own_cancellation_propagates() -> None:
    stopping, release = asyncio.Event(), asyncio.Event()
    task = asyncio.create_task(slow_to_stop(stopping, release))
    await asyncio.sleep(0)  # let the task start, so cancelling it reaches its except clause
    caller = asyncio.create_task(cancel_and_wait(task))
    await stopping.wait()
    caller.cancel()  # the caller is cancelled while it waits for the task to end
    with pytest.raises(asyncio.CancelledError):
        await caller
    assert caller.cancelled()
    release.set()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_a_task_that_failed_still_reports_its_error() -> None:
    async def boom() -> None:
        raise ValueError("bug")

    task = asyncio.create_task(boom())
    await asyncio.wait({task})
    with pytest.raises(ValueError, match="bug"):
        await cancel_and_wait(task)


async def test_none_and_finished_tasks_are_fine() -> None:
    await cancel_and_wait(None)
    task = asyncio.create_task(asyncio.sleep(0))
    await task
    await cancel_and_wait(task)
