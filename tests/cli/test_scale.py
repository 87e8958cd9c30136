"""`kybercore export-printers`: the registry on NATS back to a printers.json, driven through
Typer's CliRunner against a real nats-server."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from click.testing import Result
from pydantic import SecretStr
from typer.testing import CliRunner

from kybercore.cli.main import app
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import read_printers
from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.registry import KvRegistry
from kybercore.sim.stack import free_port

KEY = "export-s3cr3t-0123456789abcdef"
PRINTERS = [
    PrinterConfig(id="p-1", name="One", moonraker_url="http://10.0.0.1:7125", tags=["pla"]),
    PrinterConfig(
        id="p-2", name="Two", moonraker_url="http://10.0.0.2:7125", api_key=SecretStr(KEY)
    ),
]


def run(*args: str) -> Result:
    result = CliRunner().invoke(app, list(args), env={"COLUMNS": "200"})
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


async def fill(url: str) -> None:
    nc = await connect(url, "test")
    try:
        registry = KvRegistry()
        await registry.open(nc)
        assert await registry.import_if_empty(PRINTERS) == 2
    finally:
        await nc.close()


def test_the_registry_exported_with_and_without_its_keys(
    nats_server: LocalServer, tmp_path: Path
) -> None:
    asyncio.run(fill(nats_server.url))
    out = tmp_path / "printers.json"

    plain = run("export-printers", "--nats", nats_server.url, "--out", str(out))
    assert plain.exit_code == 0, plain.output
    assert "1 printers have an API key, not written (p-2)" in plain.output
    assert "2 printers written" in plain.output
    exported = read_printers(out)
    assert exported == [p.model_copy(update={"api_key": None}) for p in PRINTERS]
    assert KEY not in out.read_text()

    keyed = run("export-printers", "--nats", nats_server.url, "--out", str(out), "--with-keys")
    assert keyed.exit_code == 0, keyed.output
    assert read_printers(out) == PRINTERS
    assert out.stat().st_mode & 0o777 == 0o600
    # The previous export is kept beside it.
    backup = json.loads(out.with_name("printers.json.bak").read_text())
    assert [p["api_key"] for p in backup["printers"]] == [None, None]


def test_no_broker_is_one_clear_line_and_no_file(tmp_path: Path) -> None:
    out = tmp_path / "printers.json"
    url = f"nats://127.0.0.1:{free_port()}"
    result = run("export-printers", "--nats", url, "--out", str(out))
    assert result.exit_code == 1
    assert f"Cannot reach NATS at {url}" in result.output
    assert "Is nats-server -js running there?" in result.output
    assert not out.exists()


def test_a_worker_for_a_site_that_is_no_site_name_is_one_clear_line() -> None:
    result = run("ingest", "--nats", "nats://127.0.0.1:1", "--site", "Lab B")
    assert result.exit_code == 1
    assert "'Lab B' is not a site name: lowercase letters, digits" in result.output
