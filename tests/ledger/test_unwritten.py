"""The file of state changes a stop could not write: read back as written, and a file that
is not one (half-written by hand, another program's) set aside, not trusted, not fatal."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.ledger import unwritten
from kybercore.ledger.timeline import Change, Timeline


async def test_the_changes_and_open_intervals_come_back_as_written(
    tmp_path: Path, database: AsyncEngine
) -> None:
    path = tmp_path / "worker" / unwritten.UNWRITTEN
    assert unwritten.load(path) is None
    timeline = Timeline(database)
    timeline.take_back([], {"p1": 5.0})
    timeline.observe("p1", "printing", 10.0)
    timeline.forget(["p1"], 20.5)
    unwritten.save(path, timeline)
    assert unwritten.load(path) == (
        [Change("p1", "printing", 10.0), Change("p1", None, 20.5)],
        {"p1": 5.0},
    )
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temp file left


async def test_a_stop_keeps_the_open_intervals_ends_and_says_when_nothing_is_left(
    tmp_path: Path, database: AsyncEngine
) -> None:
    # The stop could not write (the history's write failed first): every change is in the
    # table, but the intervals still open must end at the stop, not at the next start.
    timeline = Timeline(database)
    timeline.observe("p1", "idle", 10.0)
    await timeline.flush()
    kept = unwritten.UnwrittenFile(tmp_path / unwritten.UNWRITTEN, timeline)
    assert "kept in" in await kept.keep_at_stop()
    changes, _ = unwritten.load(kept.path) or ([], {})
    assert [(c.printer, c.state) for c in changes] == [("p1", None)]
    # A fleet with nothing open and nothing unwritten: no file, and the log says so.
    empty = unwritten.UnwrittenFile(tmp_path / "other" / unwritten.UNWRITTEN, Timeline(database))
    assert await empty.keep_at_stop() == unwritten.NONE_LEFT
    assert not empty.path.exists()


@pytest.mark.parametrize(
    "text",
    [
        '{"version": 1, "changes": [["p1", "printing", 10',  # cut short
        '{"version": 2, "changes": [], "opened": {}}',
        '{"version": 1, "changes": [["p1", "dancing", 10]], "opened": {}}',
        '{"version": 1, "changes": [["p1", "idle", NaN]], "opened": {}}',
        '{"version": 1, "changes": [], "opened": {"p1": "yesterday"}}',
        "[]",
    ],
)
def test_a_file_that_is_not_one_is_set_aside_and_said(
    tmp_path: Path, text: str, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / unwritten.UNWRITTEN
    path.write_text(text)
    with caplog.at_level(logging.WARNING, logger="kybercore"):
        assert unwritten.load(path) is None
    assert not path.exists()
    assert path.with_name(path.name + ".bad").read_text() == text
    assert "not a list of unwritten state changes" in caplog.text
    assert "set aside as" in caplog.text
