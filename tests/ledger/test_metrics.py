"""``/metrics`` as the README documents it: every metric KyberCore exposes is named there
(Grafana dashboards are written from that list)."""

from __future__ import annotations

from pathlib import Path

from prometheus_client.parser import text_string_to_metric_families

from kybercore.ledger.metrics import QueueFigures, Snapshot, exposition

README = Path(__file__).parents[2] / "README.md"
SECTION = "## History, statistics, audit log and metrics"


def documented() -> str:
    """The README's section on the ledger, where the metrics are listed."""
    text = README.read_text()
    start = text.index(SECTION)
    return text[start : text.index("\n## ", start + len(SECTION))]


def test_the_readme_names_every_metric() -> None:
    snapshot = Snapshot(
        views=[], states={}, jobs={}, queue=QueueFigures(), reconnects={}, browsers=0,
        loop_lag=0.0, workers={"w1": (8, 0.01)},
    )  # fmt: skip
    text = exposition(snapshot).decode()
    names = {family.name for family in text_string_to_metric_families(text)}
    # The parser names a counter without "_total"; the README gives the sample name.
    assert len(names) >= 14
    section = documented()
    missing = sorted(name for name in names if f"`{name}" not in section)
    assert not missing, f"metrics the README does not name: {missing}"
