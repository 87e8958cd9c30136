"""The printers as notifications read them on a front (FrontNotifyPrinters), over a stand-in
for the front's views: what is no news of a printer on a front (its owner silent, a new
owner's session starting) reads as the observation before it (an owner silent marks it not
reported), and only the patches that touch an observation are heard."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, cast

from kybercore.core.view import LivePrinter, View, fuse
from kybercore.errors import UnknownPrinter
from kybercore.registry.models import PrinterConfig
from kybercore.scale.front import FrontFleet, Watcher
from kybercore.scale.front_notify import FrontNotifyPrinters, may_change_observation

P1 = PrinterConfig(id="p1", name="P1", model="Voron", moonraker_url="http://h:7125")
PRINTING = LivePrinter(
    connection="online",
    klippy_state="ready",
    status={"print_stats": {"state": "printing", "filename": "cube.gcode"}},
)


class Views:
    """What FrontNotifyPrinters reads of a FrontFleet: the registry, the owners' views
    (``copy.views``), the views as shown (marked stale), which printers no worker reports,
    and the patches as applied."""

    def __init__(self) -> None:
        self.copy = SimpleNamespace(views={})
        self.shown: dict[str, View] = {}
        self.unreported: set[str] = set()
        self.watchers: list[Watcher] = []

    def configs(self) -> list[PrinterConfig]:
        return [P1]

    def config(self, printer_id: str) -> PrinterConfig:
        if printer_id != P1.id:
            raise UnknownPrinter(printer_id)
        return P1

    def current_view(self, printer_id: str) -> View:
        self.config(printer_id)
        found: View | None = self.shown.get(printer_id) or self.copy.views.get(printer_id)
        return found if found is not None else fuse(P1, LivePrinter())

    def reported(self, printer_id: str) -> bool:
        return printer_id not in self.unreported

    def watch(self, watcher: Watcher) -> Callable[[], None]:
        self.watchers.append(watcher)
        return lambda: self.watchers.remove(watcher)

    def owner_reports(self, live: LivePrinter) -> None:
        self.copy.views[P1.id] = fuse(P1, live)


def printers() -> tuple[Views, FrontNotifyPrinters]:
    views = Views()
    return views, FrontNotifyPrinters(cast(FrontFleet, views))


def test_a_printer_no_owner_reported_yet_is_connecting() -> None:
    _views, front = printers()
    [seen] = front.all()
    assert (seen.ref.id, seen.observation.connection) == ("p1", "connecting")
    assert front.ids() == {"p1"}


def test_a_stale_view_reads_as_the_owners_last_not_reported() -> None:
    views, front = printers()
    views.owner_reports(PRINTING)
    assert front.get("p1").observation.reported
    views.shown[P1.id] = {**views.copy.views[P1.id], "connection": "stale"}
    views.unreported.add(P1.id)
    seen = front.get("p1").observation
    assert (seen.connection, seen.print_state, seen.reported) == ("online", "printing", False)
    views.unreported.clear()  # a worker reports it again: the same observation, reported
    assert front.get("p1").observation == dataclasses.replace(seen, reported=True)


def test_a_new_owner_connecting_is_no_news_of_the_printer() -> None:
    views, front = printers()
    views.owner_reports(PRINTING)
    before = front.get("p1").observation
    views.owner_reports(LivePrinter())  # the new owner's session, not connected yet
    assert front.get("p1").observation == before
    offline = dataclasses.replace(LivePrinter(), connection="offline")
    views.owner_reports(offline)  # then what it finds is news again
    assert front.get("p1").observation.connection == "offline"


def test_only_patches_touching_an_observation_are_heard() -> None:
    views, front = printers()
    heard: list[str] = []
    stop = front.listen(heard.append)
    [watcher] = views.watchers
    quiet: list[dict[str, Any]] = [
        {"extruder": {"temperature": 200.1}},
        {"job": {"progress": 0.5, "eta_seconds": 60}},
        {"updated_at": 12.5},
    ]
    loud: list[dict[str, Any] | None] = [
        None,
        {"connection": "offline"},
        {"klippy_state": "shutdown"},
        {"job": {"state": "complete"}},
        {"job": {"layer": 2}},
        {"runout": True},
    ]
    for patch in quiet + loud:
        watcher("p1", patch)
    assert heard == ["p1"] * len(loud)
    assert [may_change_observation(patch) for patch in quiet] == [False] * len(quiet)
    stop()
    assert views.watchers == []
