"""`kybercore jobs …` and `kybercore printers clear|hold|release`, through Typer's CliRunner
against real `kybercore serve` processes: the shared three-printer one (jobs held back by a
start time far ahead, so they never print on printers other tests use) and empty ones."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import Result
from typer.testing import CliRunner

from kybercore.api.auth import TokenStore, tokens_path_for
from kybercore.cli.main import app
from kybercore.registry.store import write_printers
from kybercore.sim.stack import free_port
from tests.helpers import KyberCoreServer, travel_gcode

pytestmark = pytest.mark.integration

FAR_AHEAD = "2099-01-01T00:00:00+00:00"


def run(url: str, *args: str, stdin: str | None = None, token: str = "") -> Result:
    """`kybercore ARGS...` against the server at ``url`` (as $KYBERCORE_URL)."""
    env = {"KYBERCORE_URL": url, "KYBERCORE_TOKEN": token, "COLUMNS": "200"}
    result = CliRunner().invoke(app, list(args), input=stdin, env=env)
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


@pytest.fixture
def guarded_server(tmp_path: Path) -> Iterator[tuple[KyberCoreServer, str]]:
    """A `kybercore serve` of an empty fleet that asks for tokens: (server, admin token)."""
    printers = tmp_path / "printers.json"
    write_printers(printers, [])
    _, admin = TokenStore(tokens_path_for(printers)).create("root", "admin")
    server = KyberCoreServer(printers, free_port())
    server.start()
    yield server, admin
    server.stop()


@pytest.fixture
def gcode(tmp_path: Path) -> Path:
    path = tmp_path / "bracket.gcode"
    path.write_bytes(travel_gcode(moves=4))
    return path


def test_add_list_show_and_cancel_a_job(kybercore_server: KyberCoreServer, gcode: Path) -> None:
    url = kybercore_server.url
    added = run(
        url, "jobs", "add", str(gcode), "--copies", "3", "--material", "PLA", "--tag", "test",
        "--printer", "fleet-a", "--priority", "2", "--not-before", FAR_AHEAD,
    )  # fmt: skip
    assert added.exit_code == 0, added.output
    match = re.search(r"Queued job (\d+): 3 copies of bracket.gcode \(needs (.+)\)", added.stdout)
    assert match, added.stdout
    job_id = match.group(1)
    assert match.group(2) == "PLA, tags test, only fleet-a"
    try:
        listed = run(url, "jobs", "list")
        assert listed.exit_code == 0, listed.output
        assert re.search(rf"\b{job_id}\b.*bracket\.gcode.*\bqueued\b", listed.stdout), listed.stdout

        as_json = run(url, "jobs", "list", "--json")
        jobs = {str(j["id"]): j for j in json.loads(as_json.stdout)}
        assert (jobs[job_id]["quantity"], jobs[job_id]["priority"]) == (3, 2)

        shown = run(url, "jobs", "show", job_id)
        assert shown.exit_code == 0, shown.output
        assert "0 done, 0 printing, 0 awaiting a clear, 3 left, of 3" in shown.stdout
        assert "Why it is not printing:" in shown.stdout
        assert "2099" in shown.stdout  # the start time holds it back, and /why says so

        kept = run(url, "jobs", "cancel", job_id, stdin="n\n")
        assert kept.exit_code == 1
        assert "Nothing cancelled." in kept.stdout
    finally:
        cancelled = run(url, "jobs", "cancel", job_id, "--yes")
    assert cancelled.exit_code == 0, cancelled.output
    assert f"Cancelled job {job_id} (bracket.gcode)." in cancelled.stdout
    assert job_id not in {
        str(j["id"]) for j in json.loads(run(url, "jobs", "list", "--json").stdout)
    }


def test_a_job_no_printer_could_print_is_refused_with_why(
    kybercore_server: KyberCoreServer, gcode: Path
) -> None:
    refused = run(kybercore_server.url, "jobs", "add", str(gcode), "--printer", "ghost")
    assert refused.exit_code == 2, refused.output
    assert "Error:" in refused.stderr
    assert "  - ghost: " in refused.stderr  # the reason, one line under the error


def test_hold_and_release_a_printer(kybercore_server: KyberCoreServer) -> None:
    url = kybercore_server.url
    held = run(url, "printers", "hold", "fleet-b", "--reason", "nozzle change")
    try:
        assert held.exit_code == 0, held.output
        assert "Held fleet-b" in held.stdout
        listed = run(url, "jobs", "list")
        assert listed.exit_code == 0, listed.output
    finally:
        released = run(url, "printers", "release", "fleet-b")
    assert released.exit_code == 0, released.output
    assert "Released fleet-b" in released.stdout
    # Only a plate awaiting a clear can be cleared: the server says why, exit 1.
    refused = run(url, "printers", "clear", "fleet-b", "--good")
    assert refused.exit_code == 1
    assert "Error:" in refused.stderr
    needs_verdict = run(url, "printers", "clear", "fleet-b")
    assert needs_verdict.exit_code == 2
    assert "--good or --bad" in needs_verdict.stderr


def test_errors_are_one_line_and_an_exit_code(
    guarded_server: tuple[KyberCoreServer, str],
) -> None:
    down = f"http://127.0.0.1:{free_port()}"
    unreachable = run(down, "jobs", "list")
    assert unreachable.exit_code == 1
    assert f"Cannot reach KyberCore at {down}" in unreachable.stderr

    server, admin = guarded_server
    anonymous = run(server.url, "jobs", "list")
    assert anonymous.exit_code == 1
    assert "token" in anonymous.stderr.lower()
    _, viewer = TokenStore(tokens_path_for(server.printers_file)).create("eve", "viewer")
    assert run(server.url, "jobs", "list", token=viewer).exit_code == 0
    forbidden = run(server.url, "jobs", "pause", token=viewer)
    assert forbidden.exit_code == 1
    assert "operator" in forbidden.stderr

    unknown = run(server.url, "jobs", "show", "4242", token=admin)
    assert unknown.exit_code == 1
    assert "Error:" in unknown.stderr
    no_printer = run(server.url, "printers", "clear", "ghost", "--bad", token=admin)
    assert no_printer.exit_code == 1
    assert "ghost" in no_printer.stderr
