"""The job store under races: concurrent reservations from one process, from two engines
(two processes' worth of connections) and from a second OS process, on SQLite and on
PostgreSQL. Never two attempts for one copy or one printer, never more in flight than left."""

from __future__ import annotations

import asyncio
import json
import os
import sys
from collections import Counter
from pathlib import Path

from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import open_database
from kybercore.jobs.store import JobStore
from tests.jobs.conftest import assert_consistent, new_job

PRINTERS = [f"p{n}" for n in range(12)]
ROOT = Path(__file__).resolve().parents[2]

# The second OS process: opens the database, says "ready", waits for "go", reserves the job
# on every printer at once and prints the attempts it got.
CHILD = """
import asyncio, json, sys
from kybercore.db import open_database
from kybercore.jobs.store import JobStore

async def main(url, job_id, printers):
    engine = await open_database(url)
    store = JobStore(engine)
    print("ready", flush=True)
    await asyncio.to_thread(sys.stdin.readline)
    got = await asyncio.gather(*(store.reserve(job_id, p, "child") for p in printers))
    print(json.dumps([a.id for a in got if a is not None]), flush=True)
    await engine.dispose()

asyncio.run(main(sys.argv[1], int(sys.argv[2]), sys.argv[3:]))
"""


async def test_concurrent_reservations_take_each_copy_once(store: JobStore) -> None:
    job = await store.create_job(new_job(3), "ana")
    got = await asyncio.gather(*(store.reserve(job.id, p) for p in PRINTERS))
    attempts = [a for a in got if a is not None]
    assert sorted(a.copy for a in attempts) == [1, 2, 3]
    assert (await store.job(job.id)).in_flight == 3
    await assert_consistent(store)


async def test_concurrent_reservations_of_one_printer_give_it_one_attempt(
    store: JobStore,
) -> None:
    jobs = [await store.create_job(new_job(2), "ana") for _ in range(4)]
    got = await asyncio.gather(*(store.reserve(j.id, "p1") for j in jobs for _ in range(3)))
    assert len([a for a in got if a is not None]) == 1
    assert sum(j.in_flight for j in await store.jobs()) == 1
    await assert_consistent(store)


async def test_two_engines_on_one_database_never_double_book(database_url: str) -> None:
    one, two = await asyncio.gather(open_database(database_url), open_database(database_url))
    try:
        a, b = JobStore(one), JobStore(two)
        job = await a.create_job(new_job(5), "ana")
        got = await asyncio.gather(
            *(store.reserve(job.id, p) for p in PRINTERS for store in (a, b))
        )
        attempts = [x for x in got if x is not None]
        assert sorted(x.copy for x in attempts) == [1, 2, 3, 4, 5]
        assert max(Counter(x.printer for x in attempts).values()) == 1
        await assert_consistent(b)
    finally:
        await one.dispose()
        await two.dispose()


async def test_a_storm_of_reserves_ends_and_clears_from_two_engines_prints_exactly_quantity(
    database_url: str,
) -> None:
    """Rounds of everything at once from two engines: reserve on every printer, end each
    attempt (completed or failed), clear each plate (good or bad). The job ends with
    exactly its quantity of good copies, and the books hold after every round."""
    one, two = await asyncio.gather(open_database(database_url), open_database(database_url))
    try:
        stores = (JobStore(one), JobStore(two))
        job = await stores[0].create_job(new_job(7, max_attempts=100), "ana")
        for round_ in range(30):
            if (await stores[0].job(job.id)).state == "done":
                break
            got = await asyncio.gather(
                *(s.reserve(job.id, p) for i, p in enumerate(PRINTERS[:6]) for s in stores)
            )
            attempts = [x for x in got if x is not None]
            await asyncio.gather(
                *(
                    stores[i % 2].finish(x.id, "completed" if (i + round_) % 3 else "failed")
                    for i, x in enumerate(attempts)
                )
            )
            await asyncio.gather(
                *(
                    stores[i % 2].clear(x.printer, "bad" if (i + round_) % 4 == 0 else "good",
                                        user="ana")
                    for i, x in enumerate(attempts)
                )
            )  # fmt: skip
            await assert_consistent(stores[1])
        final = await stores[1].job(job.id)
        assert (final.state, final.done, final.in_flight) == ("done", 7, 0)
    finally:
        await one.dispose()
        await two.dispose()


async def test_a_second_process_on_the_same_database_never_double_books(
    database: AsyncEngine, database_url: str
) -> None:
    store = JobStore(database)
    job = await store.create_job(new_job(6), "ana")
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}{os.pathsep}{ROOT}"}
    child = await asyncio.create_subprocess_exec(
        sys.executable, "-c", CHILD, database_url, str(job.id), *PRINTERS,
        stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, env=env,
    )  # fmt: skip
    assert child.stdin is not None
    assert child.stdout is not None
    try:
        assert await asyncio.wait_for(child.stdout.readline(), 60) == b"ready\n"
        child.stdin.write(b"go\n")
        await child.stdin.drain()
        mine = await asyncio.gather(*(store.reserve(job.id, p, "parent") for p in PRINTERS))
        theirs = json.loads(await asyncio.wait_for(child.stdout.readline(), 60))
    finally:
        if child.returncode is None:
            child.kill()
        await child.wait()
    ours = [a.id for a in mine if a is not None]
    assert len(ours) + len(theirs) == 6
    attempts = await store.attempts(job.id)
    assert sorted(a.id for a in attempts) == sorted(ours + theirs)
    assert sorted(a.copy for a in attempts) == [1, 2, 3, 4, 5, 6]
    await assert_consistent(store)
