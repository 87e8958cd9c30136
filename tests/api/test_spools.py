"""Spoolman through each printer's Moonraker ([spoolman]): the active spool on the printer's
view and in the spool map (GET /api/spools), its remaining weight refusing a start that
needs more, the queue saying why it skips the printer and dispatching as soon as a fuller
spool is set. Real Moonraker + Klippy; Spoolman itself is a fake (tests/fake_spoolman.py
says why)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import httpx
import pytest

from kybercore.core.spools import LOW_FILAMENT_G
from kybercore.jobs.dispatcher import TICK_SECONDS as DISPATCHER_TICK
from kybercore.sim.stack import PrinterStack
from tests.api.conftest import StartEdge, add_printer
from tests.fake_spoolman import FakeSpoolman, printer_with_spoolman, spool
from tests.helpers import wait_until
from tests.web.support import SAMPLE

pytestmark = pytest.mark.integration

FULL, NEARLY_EMPTY = 1, 2  # the sample file needs 0.80 g


@pytest.fixture(scope="module")
def spoolman() -> Iterator[FakeSpoolman]:
    server = FakeSpoolman(
        [spool(FULL, "PLA", "D62828", 812.4), spool(NEARLY_EMPTY, "PLA", "1E88E5", 0.5)]
    )
    server.start()
    yield server
    server.stop()


@pytest.fixture(scope="module")
def spool_printer(
    start_stack: Callable[..., PrinterStack], spoolman: FakeSpoolman
) -> Iterator[PrinterStack]:
    stack = printer_with_spoolman(start_stack, "spools", spoolman)
    yield stack
    stack.stop()


def set_active(stack: PrinterStack, spool_id: int) -> None:
    """What Mainsail does when the user picks a spool."""
    answer = httpx.post(f"{stack.url}/server/spoolman/spool_id", json={"spool_id": spool_id})
    assert answer.status_code == 200, answer.text


def view(server_url: str) -> dict[str, object]:
    body: dict[str, object] = httpx.get(f"{server_url}/api/printers/spools", timeout=30).json()
    return body


def spool_id(server_url: str) -> object:
    shown = view(server_url)["spool"]
    return shown.get("id") if isinstance(shown, dict) else None


def test_the_spool_is_shown_and_too_little_filament_refuses_a_start(
    edge_server: StartEdge, spool_printer: PrinterStack
) -> None:
    set_active(spool_printer, NEARLY_EMPTY)
    server, _ = edge_server()
    add_printer(server, "spools", spool_printer.url)
    wait_until(lambda: view(server.url)["spool"] is not None, timeout=30, what="the spool")
    assert view(server.url)["spool"] == {
        "id": NEARLY_EMPTY, "name": "Acme Basic PLA", "material": "PLA",
        "color_hex": "1E88E5", "remaining_g": 0.5, "low": True,
    }  # fmt: skip
    uploaded = httpx.post(
        f"{server.url}/api/printers/spools/files",
        files={"file": (SAMPLE.name, SAMPLE.read_bytes())},
        timeout=60,
    )
    assert uploaded.status_code == 201, uploaded.text
    check = httpx.post(
        f"{server.url}/api/printers/spools/actions/start/check",
        json={"filename": SAMPLE.name},
        timeout=30,
    ).json()
    [short] = [r for r in check["reasons"] if r["code"] == "not_enough_filament"]
    assert short["level"] == "block"
    assert "needs 0.8 g of filament but the loaded spool has 0.5 g left" in short["en"]
    assert "necesita 0,8 g de filamento" in short["es"]

    # The queue skips the printer, and says why.
    job = httpx.post(
        f"{server.url}/api/jobs",
        files={"file": ("queued.gcode", SAMPLE.read_bytes())},
        data={"material": "PLA"},
        timeout=60,
    )
    assert job.status_code == 201, job.text
    job_id = job.json()["id"]
    why = httpx.get(f"{server.url}/api/jobs/{job_id}/why", timeout=30).json()
    assert [line["code"] for line in why] == ["not_enough_filament"], why
    assert "0.5 g left" in why[0]["en"]
    assert job_state(server.url, job_id)["in_flight"] == 0

    # Another spool set active (Mainsail, KlipperScreen): KyberCore hears it at once.
    set_active(spool_printer, FULL)
    wait_until(lambda: spool_id(server.url) == FULL, what="spool 1 on the view")
    check = httpx.post(
        f"{server.url}/api/printers/spools/actions/start/check",
        json={"filename": SAMPLE.name},
        timeout=30,
    )
    assert "not_enough_filament" not in [r["code"] for r in check.json()["reasons"]]
    # ...and so does the queue: the new spool replans at once, not at the slow tick (30 s).
    wait_until(
        lambda: job_state(server.url, job_id)["in_flight"] == 1,
        timeout=DISPATCHER_TICK / 2,
        what="the job dispatched on the fuller spool",
    )


def job_state(server_url: str, job_id: int) -> dict[str, object]:
    body: dict[str, object] = httpx.get(f"{server_url}/api/jobs/{job_id}", timeout=30).json()
    return body


def test_the_spool_map_names_each_spool_with_its_printer_and_the_printers_without(
    edge_server: StartEdge, spool_printer: PrinterStack, printer: PrinterStack
) -> None:
    set_active(spool_printer, NEARLY_EMPTY)
    server, _ = edge_server()
    add_printer(server, "spools", spool_printer.url)
    add_printer(server, "plain", printer.url)  # no [spoolman] in its moonraker.conf

    def spools() -> dict[str, object]:
        answer = httpx.get(f"{server.url}/api/spools", timeout=30)
        assert answer.status_code == 200, answer.text
        body: dict[str, object] = answer.json()
        return body

    wait_until(lambda: bool(spools()["spools"]), timeout=30, what="the spool map")
    wait_until(
        lambda: spools()["without"] == [{"id": "plain", "name": "Plain", "spoolman": "absent"}],
        what="the printer without Spoolman",
    )
    mapped = spools()
    assert mapped["spools"] == [
        {
            "id": NEARLY_EMPTY, "name": "Acme Basic PLA", "material": "PLA",
            "color_hex": "1E88E5", "remaining_g": 0.5, "low": True,
            "printers": [{"id": "spools", "name": "Spools"}],
        }
    ]  # fmt: skip
    assert mapped["low_below_g"] == LOW_FILAMENT_G
    assert view(server.url)["spoolman"] == "active"
