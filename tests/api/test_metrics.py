"""``GET /metrics`` on a real `kybercore serve` over real printers: Prometheus' own parser
reads it, and its values are those ``/api/printers`` and the ledger show at that instant."""

from __future__ import annotations

from collections import Counter
from collections.abc import AsyncIterator
from typing import Any

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from kybercore.api.auth import TokenStore, tokens_path_for
from tests.api.conftest import StartEdge
from tests.browser_mirror import BrowserMirror
from tests.helpers import KyberCoreServer, wait_for

pytestmark = pytest.mark.integration

Samples = dict[str, dict[tuple[tuple[str, str], ...], float]]


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


def parse(text: str) -> Samples:
    """Every sample by name, then by its sorted labels."""
    samples: Samples = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            labels = tuple(sorted(sample.labels.items()))
            samples.setdefault(sample.name, {})[labels] = sample.value
    return samples


async def same_instant(api: httpx.AsyncClient) -> tuple[list[dict[str, Any]], Samples]:
    """``/api/printers`` and ``/metrics`` at one instant: the fleet read before and after the
    scrape is the same (the published views change at most every 100 ms)."""
    result: list[tuple[list[dict[str, Any]], Samples]] = []

    async def steady() -> bool:
        before = (await api.get("/api/printers")).json()
        scrape = await api.get("/metrics")
        after = (await api.get("/api/printers")).json()
        assert scrape.status_code == 200
        assert scrape.headers["content-type"].startswith("text/plain")
        if before != after:
            return False
        result.append((after, parse(scrape.text)))
        return True

    await wait_for(steady, 30, "a scrape between two equal reads of the fleet")
    return result[-1]


async def test_metrics_parse_and_equal_the_fleet_at_the_same_instant(
    api: httpx.AsyncClient, kybercore_server: KyberCoreServer
) -> None:
    async with BrowserMirror(kybercore_server.ws_url):
        views, samples = await same_instant(api)
        health = (await api.get("/api/health")).json()
    by_state = Counter((v["connection"], v["klippy_state"]) for v in views)
    assert {
        dict(labels)["connection"] + "/" + dict(labels)["klippy_state"]: value
        for labels, value in samples["kybercore_printers"].items()
    } == {f"{c}/{k}": n for (c, k), n in by_state.items()}
    for view in views:
        printer = view["id"]
        for heater in ("extruder", "bed"):
            key = (("heater", heater), ("printer", printer))
            assert samples["kybercore_heater_temperature_celsius"].get(key) == view[heater][
                "temperature"
            ], (printer, heater)
            assert samples["kybercore_heater_target_celsius"].get(key) == view[heater]["target"]
        progress = (("printer", printer), ("state", view["job"]["state"]))
        assert samples["kybercore_print_progress_ratio"][progress] == view["job"]["progress"]
    assert samples["kybercore_browser_clients"][()] == health["browsers"] >= 1
    assert samples["kybercore_event_loop_lag_seconds"][()] >= 0
    for name in ("kybercore_queue_jobs", "kybercore_queue_copies_left"):
        assert samples[name][()] >= 0
    states = samples["kybercore_printer_state"]
    assert {dict(labels)["printer"] for labels in states} == {v["id"] for v in views}


async def test_jobs_by_outcome_equal_the_ledgers_statistics(api: httpx.AsyncClient) -> None:
    async def equal() -> bool:
        samples = parse((await api.get("/metrics")).text)
        window = {"from": "1970-01-02T00:00:00Z", "to": "2100-01-01T00:00:00Z"}
        rows = (await api.get("/api/stats", params={"group_by": "printer", **window})).json()
        ledger = {
            (row["key"], outcome): n for row in rows["rows"] for outcome, n in row["jobs"].items()
        }
        metrics = {
            (dict(labels)["printer"], dict(labels)["outcome"]): value
            for labels, value in samples.get("kybercore_jobs_total", {}).items()
        }
        return metrics == ledger

    # A print finishing between the two reads moves one of them: read again.
    await wait_for(equal, 30, "jobs_total equal to the ledger's statistics")


async def test_metrics_need_a_viewer_token_once_tokens_exist(edge_server: StartEdge) -> None:
    server, _admin = edge_server(tokens=True)
    _, viewer = TokenStore(tokens_path_for(server.printers_file)).create("grafana", "viewer")
    async with httpx.AsyncClient(base_url=server.url, timeout=30) as client:
        assert (await client.get("/metrics")).status_code == 401
        answer = await client.get("/metrics", headers={"Authorization": f"Bearer {viewer}"})
        assert answer.status_code == 200
        samples = parse(answer.text)
        assert samples.get("kybercore_printers", {}) == {}  # an empty fleet
        assert samples["kybercore_browser_clients"][()] == 0
