"""``GET /metrics`` on a real `kybercore serve` over real printers: Prometheus' own parser
reads it, and its values are those ``/api/printers`` and the ledger show at that instant."""

from __future__ import annotations

from collections.abc import AsyncIterator

import httpx
import pytest

from kybercore.api.auth import TokenStore, tokens_path_for
from tests.api.conftest import StartEdge
from tests.browser_mirror import BrowserMirror
from tests.helpers import KyberCoreServer, wait_for
from tests.metrics_scrape import assert_printers_as_viewed, jobs_as_in_stats, parse, same_instant

pytestmark = pytest.mark.integration


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


async def test_metrics_parse_and_equal_the_fleet_at_the_same_instant(
    api: httpx.AsyncClient, kybercore_server: KyberCoreServer
) -> None:
    async with BrowserMirror(kybercore_server.ws_url):
        views, samples = await same_instant(api)
        health = (await api.get("/api/health")).json()
    assert_printers_as_viewed(views, samples)
    assert samples["kybercore_browser_clients"][()] == health["browsers"] >= 1
    assert samples["kybercore_event_loop_lag_seconds"][()] >= 0
    for name in ("kybercore_queue_jobs", "kybercore_queue_copies_left"):
        assert samples[name][()] >= 0
    states = samples["kybercore_printer_state"]
    assert {dict(labels)["printer"] for labels in states} == {v["id"] for v in views}


async def test_jobs_by_outcome_equal_the_ledgers_statistics(api: httpx.AsyncClient) -> None:
    # A print finishing between the two reads moves one of them: read again.
    await wait_for(lambda: jobs_as_in_stats(api), 30, "jobs_total equal to the ledger's statistics")


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
