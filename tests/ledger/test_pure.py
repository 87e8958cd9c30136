"""The ledger's pure parts: reading Moonraker's history records, paging a backfill, and
naming a printer's state."""

from __future__ import annotations

import math
from typing import Any

import pytest

from kybercore.ledger.history import backfill, jobs_of_notification, parse_job
from kybercore.ledger.timeline import printer_state


def record(number: int, **fields: Any) -> dict[str, Any]:
    """A job as Moonraker 0.11's history returns it."""
    return {
        "job_id": f"{number:06X}",
        "user": "No User",
        "filename": f"part-{number}.gcode",
        "status": "completed",
        "start_time": 1_700_000_000.0 + number * 100,
        "end_time": 1_700_000_050.0 + number * 100,
        "print_duration": 40.0,
        "total_duration": 50.0,
        "filament_used": 123.4,
        "metadata": {"size": 1000, "filament_type": "PLA", "thumbnails": [{"width": 32}]},
        "auxiliary_data": [],
        "exists": True,
        **fields,
    }


def test_a_history_record_is_read_with_what_identifies_it() -> None:
    job = parse_job(record(26))
    assert job is not None
    assert (job.job_id, job.number, job.status, job.user) == ("00001A", 26, "completed", "")
    assert job.material == "PLA"
    assert "thumbnails" not in job.meta
    assert job.filament_g is None  # the file does not say what its filament weighs


def test_grams_are_the_used_share_of_the_files_weight() -> None:
    meta = {"filament_total": 1000.0, "filament_weight_total": 3.0}
    job = parse_job(record(1, filament_used=250.0, status="cancelled", metadata=meta))
    assert job is not None
    assert job.filament_g == pytest.approx(0.75)


@pytest.mark.parametrize(
    "bad",
    [
        None, [], "x", {}, {"job_id": "00000G", "start_time": 1.0},
        {"job_id": 1, "start_time": 1.0}, {"job_id": "000001"},
        {"job_id": "000001", "start_time": math.nan}, {"job_id": "000001", "start_time": True},
    ],
)  # fmt: skip
def test_a_record_without_an_id_or_start_is_skipped(bad: Any) -> None:
    assert parse_job(bad) is None


def test_junk_fields_become_defaults_not_errors() -> None:
    job = parse_job(
        {"job_id": "000002", "start_time": "5", "end_time": "x", "print_duration": None,
         "filament_used": [], "metadata": "?", "user": 7, "status": None}
    )  # fmt: skip
    assert job is not None
    assert (job.start_time, job.end_time, job.print_duration, job.filament_used) == (
        5.0, None, 0.0, 0.0,
    )  # fmt: skip
    assert (job.meta, job.user, job.status) == ({}, "", "in_progress")


def test_a_history_notification_carries_added_and_finished_jobs() -> None:
    params = [
        {"action": "added", "job": record(3, status="in_progress")},
        {"action": "finished", "job": record(3)},
        {"action": "deleted", "job": record(2)},
        "junk",
    ]
    assert [(j.job_id, j.status) for j in jobs_of_notification(params)] == [
        ("000003", "in_progress"),
        ("000003", "completed"),
    ]


class History:
    """Moonraker's /server/history/list over ``jobs`` (numbers; some may be missing),
    newest first, counting the requests."""

    def __init__(self, numbers: list[int]) -> None:
        self.newest_first = sorted(numbers, reverse=True)
        self.requests = 0

    async def page(self, limit: int, start: int) -> dict[str, Any]:
        self.requests += 1
        jobs = [record(n) for n in self.newest_first[start : start + limit]]
        return {"count": len(jobs), "jobs": jobs}


async def read_all(history: History, floor: int, limit: int) -> list[int]:
    return [job.number async for page in backfill(history.page, floor, limit) for job in page]


@pytest.mark.parametrize(
    ("count", "limit"), [(5000, 100), (5000, 50), (5001, 100), (99, 100), (0, 50)]
)
async def test_a_first_backfill_reads_everything_in_ceil_count_over_limit_requests(
    count: int, limit: int
) -> None:
    history = History(list(range(1, count + 1)))
    assert await read_all(history, 0, limit) == list(range(count, 0, -1))
    assert history.requests == max(1, math.ceil(count / limit))


async def test_a_later_backfill_stops_at_the_floor_included() -> None:
    history = History(list(range(1, 5001)))
    assert await read_all(history, 4990, 100) == list(range(5000, 4900, -1))
    assert history.requests == 1
    history.requests = 0
    read = await read_all(history, 4850, 100)
    assert read[-1] == 4801
    assert 4850 in read
    assert history.requests == 2


async def test_deleted_jobs_cost_at_most_one_more_request() -> None:
    history = History([n for n in range(1, 1001) if n % 7])  # every 7th job deleted
    read = await read_all(history, 0, 100)
    assert sorted(read) == sorted(history.newest_first)
    assert history.requests <= math.ceil(len(read) / 100) + 1


@pytest.mark.parametrize(
    ("connection", "klippy", "printing", "gate", "state"),
    [
        ("disabled", "disconnected", "", "maintenance", "disabled"),
        ("offline", "disconnected", "", None, "offline"),
        ("connecting", "disconnected", "", "available", "offline"),
        ("auth_failed", "disconnected", "", None, "offline"),
        ("offline", "disconnected", "", "maintenance", "maintenance"),
        ("online", "startup", "", None, "offline"),
        ("online", "shutdown", "printing", None, "error"),
        ("online", "error", "", "awaiting_clear", "error"),
        ("online", "ready", "printing", "maintenance", "printing"),
        ("online", "ready", "paused", None, "paused"),
        ("online", "ready", "complete", "awaiting_clear", "awaiting_clear"),
        ("online", "ready", "cancelled", "held", "idle"),
        ("online", "ready", "standby", None, "idle"),
        ("online", "ready", "error", "available", "idle"),
    ],
)
def test_printer_state(
    connection: str, klippy: str, printing: str, gate: str | None, state: str
) -> None:
    assert printer_state(connection, klippy, printing, gate) == state
