"""``cancel_and_wait``: it waits for the task it cancels, and never eats its caller's own
cancellation. ``Remembered``: one lookup per key in flight, answers kept, failures not."""

from __future__ import annotations

import asyncio

import pytest

from kybercore.aio import Remembered, cancel_and_wait


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


async def test_remembered_asks_once_for_many_callers_and_retries_a_failure() -> None:
    calls: list[str] = []
    release = asyncio.Event()

    async def look_up() -> str:
        calls.append("ask")
        await release.wait()
        if len(calls) == 1:
            raise OSError("down")
        return "answer"

    known: Remembered[str, str] = Remembered(60)
    waiting = [asyncio.ensure_future(known.get("host", look_up)) for _ in range(3)]
    release.set()
    outcomes = await asyncio.gather(*waiting, return_exceptions=True)
    assert calls == ["ask"]  # one lookup for three callers
    assert all(isinstance(o, OSError) for o in outcomes)
    assert await known.get("host", look_up) == "answer"  # the failure was not kept
    assert await known.get("host", look_up) == "answer"
    assert calls == ["ask", "ask"]  # the answer was


async def test_remembered_forgets_after_its_time() -> None:
    answers = iter(["old", "new"])

    async def look_up() -> str:
        return next(answers)

    known: Remembered[str, str] = Remembered(0)
    assert await known.get("k", look_up) == "old"
    assert await known.get("k", look_up) == "new"
