"""The `kybercore` command's own behaviour (serve refuses what it cannot run)."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest
from typer.testing import CliRunner

from kybercore import __version__
from kybercore.cli.main import app
from kybercore.sim.stack import free_port

runner = CliRunner()


def test_serve_refuses_a_broken_printers_json_naming_line_and_reason(tmp_path: Path) -> None:
    # A long folder (a CI workspace, a long home) must not wrap the message at 80 columns.
    deep = tmp_path / ("long-folder-name-" * 8) / "[farm]"
    deep.mkdir(parents=True)
    broken = deep / "printers.json"
    broken.write_text('{"version": 1,\n "printers": [\n  {"id": "a",, }\n ]}\n')
    port = str(free_port())  # the check of the port comes first: it must pass
    result = runner.invoke(app, ["serve", "--printers-file", str(broken), "--port", port])
    assert result.exit_code == 1
    error_line = next(line for line in result.output.splitlines() if "Error:" in line)
    assert "line 3" in error_line
    assert str(broken) in error_line
    assert "Traceback" not in result.output
    assert broken.read_text().startswith('{"version": 1,')  # untouched


def test_serve_refuses_a_port_in_use(tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = runner.invoke(
            app, ["serve", "--port", str(port), "--printers-file", str(tmp_path / "p.json")]
        )
    assert result.exit_code == 1
    assert f"127.0.0.1:{port}" in result.output
    assert "--port" in result.output


def test_version() -> None:
    result = runner.invoke(app, ["version"])
    assert result.exit_code == 0
    assert result.output.startswith(__version__)
    assert "compiled hot path: " in result.output  # on or off, and why (kybercore/native.py)


def test_serve_names_an_allowed_host_that_is_not_a_host_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The variable holds a list (commas or spaces), as a proxy's setup writes it.
    monkeypatch.setenv("KYBERCORE_ALLOWED_HOSTS", "printers.lan,proxy.lan bad/name")
    # 0.0.0.0 without a token: even a check that let the name through ends in an exit.
    printers = str(tmp_path / "p.json")
    result = runner.invoke(app, ["serve", "--host", "0.0.0.0", "--printers-file", printers])
    assert result.exit_code == 1
    assert "--allowed-host 'bad/name' is not a host name" in result.output


def test_serve_refuses_an_unusable_database_url_in_one_line(tmp_path: Path) -> None:
    printers = str(tmp_path / "p.json")
    port = str(free_port())
    result = runner.invoke(
        app, ["serve", "--printers-file", printers, "--port", port, "--database-url", "nonsense"]
    )
    assert result.exit_code == 1
    assert "Traceback" not in result.output
    error = next(line for line in result.output.splitlines() if "Error:" in line)
    assert "The database URL is not a URL" in error
    assert "postgresql+asyncpg://" in error
