"""A background task's outage in the log: a line when it begins, one for each other kind of
failure meanwhile, one when it ends (:class:`kybercore.db.outage.Outage`)."""

from __future__ import annotations

import logging

import pytest

from kybercore.db.outage import Outage
from kybercore.errors import ActionRejected, DatabaseUnavailable

log = logging.getLogger("kybercore.test_outage")


def lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records]


def test_an_outage_is_said_once_when_it_begins_and_once_when_it_ends(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger=log.name)
    outage = Outage(log, "plan the queue", "it tries again every 5 s")
    outage.ended()  # nothing failed: nothing to say
    for _ in range(3):
        outage.failed(DatabaseUnavailable("The database x does not answer"))
    outage.ended()
    outage.ended()
    said = lines(caplog)
    assert len(said) == 2, said
    assert said[0] == (
        "cannot plan the queue (the database does not answer: DatabaseUnavailable: The "
        "database x does not answer); it tries again every 5 s."
    )
    assert said[1].startswith("can plan the queue again (it could not for ")


def test_another_kind_of_failure_meanwhile_is_said_too(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger=log.name)
    outage = Outage(log, "plan the queue", "it tries again every 5 s")
    outage.failed(DatabaseUnavailable("away"))
    outage.failed(ActionRejected("the plate is not cleared"))
    outage.failed(DatabaseUnavailable("away"))
    outage.failed(ActionRejected("the plate is not cleared"))
    assert len(lines(caplog)) == 2
    assert "ActionRejected: the plate is not cleared" in lines(caplog)[1]
    outage.ended()
    # A new outage: said again from its first failure.
    outage.failed(ActionRejected("the plate is not cleared"))
    assert len(lines(caplog)) == 4
