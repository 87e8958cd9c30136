"""Reading ``GET /metrics`` in tests: Prometheus' own parser, a scrape taken between two
equal reads of the fleet, and the printer figures compared with the views."""

from __future__ import annotations

from collections import Counter
from typing import Any

import httpx
from prometheus_client.parser import text_string_to_metric_families

from tests.helpers import wait_for

Samples = dict[str, dict[tuple[tuple[str, str], ...], float]]


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
        assert scrape.status_code == 200, scrape.text
        assert scrape.headers["content-type"].startswith("text/plain")
        if before != after:
            return False
        result.append((after, parse(scrape.text)))
        return True

    await wait_for(steady, 30, "a scrape between two equal reads of the fleet")
    return result[-1]


def by_state(samples: Samples) -> dict[str, float]:
    """``kybercore_printers`` as ``{"connection/klippy_state": count}``."""
    return {
        dict(labels)["connection"] + "/" + dict(labels)["klippy_state"]: value
        for labels, value in samples.get("kybercore_printers", {}).items()
    }


def assert_printers_as_viewed(views: list[dict[str, Any]], samples: Samples) -> None:
    """Every printer counted by its state, and its heaters and progress, as its view has them."""
    counted = Counter((v["connection"], v["klippy_state"]) for v in views)
    assert by_state(samples) == {f"{c}/{k}": n for (c, k), n in counted.items()}
    for view in views:
        printer = view["id"]
        for heater in ("extruder", "bed"):
            key = (("heater", heater), ("printer", printer))
            assert (
                samples["kybercore_heater_temperature_celsius"].get(key)
                == view[heater]["temperature"]
            ), (printer, heater)
            assert samples["kybercore_heater_target_celsius"].get(key) == view[heater]["target"]
        progress = (("printer", printer), ("state", view["job"]["state"]))
        assert samples["kybercore_print_progress_ratio"][progress] == view["job"]["progress"]


async def jobs_as_in_stats(api: httpx.AsyncClient) -> bool:
    """Whether ``kybercore_jobs_total`` holds the jobs by printer and outcome that the
    ledger's statistics (``/api/stats``) count, read one after the other."""
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
