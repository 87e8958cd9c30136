"""`kybercore notify …` through Typer's CliRunner against a real `kybercore serve` (an empty
fleet) and a real loopback webhook receiver: add a channel, list it, test it, read the log."""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import Result
from typer.testing import CliRunner

from kybercore.cli.main import app
from kybercore.notify.senders import verify
from kybercore.registry.store import write_printers
from kybercore.sim.stack import free_port
from tests.helpers import KyberCoreServer
from tests.notify.receiver import Receiver


async def run(url: str, *args: str, stdin: str | None = None) -> Result:
    """`kybercore ARGS...` against the server at ``url``, in a worker thread: the receiver
    it may reach runs on this loop."""

    def invoke() -> Result:
        env = {"KYBERCORE_URL": url, "KYBERCORE_TOKEN": "", "COLUMNS": "200"}
        return CliRunner().invoke(app, list(args), input=stdin, env=env)

    result = await asyncio.to_thread(invoke)
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


@pytest.fixture
def server(tmp_path: Path) -> Iterator[KyberCoreServer]:
    """An open `kybercore serve` of an empty fleet."""
    printers = tmp_path / "printers.json"
    write_printers(printers, [])
    started = KyberCoreServer(printers, free_port())
    started.start()
    yield started
    started.stop()


async def test_add_list_test_and_read_the_deliveries_of_a_webhook(
    server: KyberCoreServer, receiver: Receiver
) -> None:
    url = server.url
    added = await run(
        url, "notify", "add", "night shift", receiver.url(), "--event", "print_failed",
        "--event", "printer_offline", "--location", "Room B", "--quiet", "22:00-07:00",
        "--language", "es", "--min-role", "operator",
    )  # fmt: skip
    assert added.exit_code == 0, added.output
    match = re.search(r"Added channel (\d+) \(night shift, webhook\)", added.stdout)
    assert match, added.stdout
    channel_id = match.group(1)
    secret = added.stdout.strip().splitlines()[-1]
    assert len(secret) >= 32

    listed = await run(url, "notify", "channels")
    assert listed.exit_code == 0, listed.output
    assert re.search(rf"\b{channel_id}\b.*night shift.*webhook", listed.stdout), listed.stdout
    assert "print_failed, printer_offline" in listed.stdout
    assert "quiet 22:00-07:00" in listed.stdout
    assert secret not in listed.stdout
    [shown] = json.loads((await run(url, "notify", "channels", "--json")).stdout)
    assert shown["rules"]["locations"] == ["Room B"]

    tested = await run(url, "notify", "test", channel_id)
    assert tested.exit_code == 0, tested.output
    assert "Delivered to night shift (HTTP 200)" in tested.stdout
    [request] = receiver.accepted
    assert verify(
        secret, request.headers["x-kybercore-timestamp"], request.body,
        request.headers["x-kybercore-signature"],
    )  # fmt: skip
    assert request.json()["title"] == "Notificación de prueba de KyberCore"

    log = await run(url, "notify", "deliveries", "--channel", channel_id)
    assert log.exit_code == 0, log.output
    row = r"night shift.*Notificación de prueba.*delivered\W+1\b"
    assert re.search(row, log.stdout), log.stdout


async def test_a_failed_test_a_bad_url_and_the_settings(server: KyberCoreServer) -> None:
    url = server.url
    down = Receiver()  # never started
    added = await run(url, "notify", "add", "down", down.url())
    channel_id = re.search(r"Added channel (\d+)", added.stdout).group(1)  # type: ignore[union-attr]
    tested = await run(url, "notify", "test", channel_id)
    assert tested.exit_code == 1
    assert "Not delivered to down: Could not reach the receiver" in tested.output

    bad = await run(url, "notify", "add", "bad", "ftp://example/x")
    assert bad.exit_code == 2
    assert "target: must be an http:// or https:// URL" in bad.output

    shown = await run(url, "notify", "settings")
    assert "cooldown: 300" in shown.stdout
    changed = await run(url, "notify", "settings", "--cooldown", "60", "--storm-threshold", "8")
    assert changed.exit_code == 0, changed.output
    assert "cooldown: 60" in changed.stdout
    assert "storm-threshold: 8" in changed.stdout

    removed = await run(url, "notify", "remove", channel_id, "--yes")
    assert removed.exit_code == 0, removed.output
    assert "No channels" in (await run(url, "notify", "channels")).stdout
