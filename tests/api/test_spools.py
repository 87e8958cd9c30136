"""Spoolman through each printer's Moonraker ([spoolman]): the active spool on the printer's
view, its remaining weight refusing a start that needs more, and the queue saying why it
skips the printer. Real Moonraker + Klippy; Spoolman itself is a fake (tests/fake_spoolman.py
says why)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import httpx
import pytest

from kybercore.sim.stack import PrinterStack
from tests.api.conftest import StartEdge, add_printer
from tests.fake_spoolman import FakeSpoolman, printer_with_spoolman, spool
from tests.web.support import SAMPLE, wait_until

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
        "color_hex": "1E88E5", "remaining_g": 0.5,
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
    assert any("0.5 g left" in line["en"] for line in why), why
    cancelled = httpx.delete(f"{server.url}/api/jobs/{job_id}", params={"confirm": "true"})
    assert cancelled.status_code == 200, cancelled.text

    # Another spool set active (Mainsail, KlipperScreen): KyberCore hears it at once.
    set_active(spool_printer, FULL)
    wait_until(lambda: spool_id(server.url) == FULL, what="spool 1 on the view")
    check = httpx.post(
        f"{server.url}/api/printers/spools/actions/start/check",
        json={"filename": SAMPLE.name},
        timeout=30,
    ).json()
    assert "not_enough_filament" not in [r["code"] for r in check["reasons"]]
