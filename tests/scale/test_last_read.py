"""The printers a worker last read from the registry, on its disk: written whole after each
change (API keys included, so 0600), and read back to start on
(:mod:`kybercore.scale.last_read`)."""

from __future__ import annotations

import asyncio
import logging
import stat
from pathlib import Path

import pytest
from pydantic import SecretStr

from kybercore.registry.models import PrinterConfig
from kybercore.scale.last_read import LastRead
from tests.helpers import wait_for


def printers(*names: str) -> list[PrinterConfig]:
    return [
        PrinterConfig(
            id=n,
            name=n,
            site="lab-b",
            moonraker_url="http://127.0.0.1:7125",
            api_key=SecretStr(f"key-{n}"),
        )
        for n in names
    ]


async def test_the_newest_list_is_written_and_read_back_with_its_keys(tmp_path: Path) -> None:
    last = LastRead(tmp_path)
    assert await last.load() is None  # never written: nothing to start on
    writer = asyncio.create_task(last.run())
    try:
        last.keep(printers("a"))
        last.keep(printers("a", "b"))  # noted while the first may be written: the newest wins

        async def written() -> bool:
            found = await last.load()
            return found is not None and [p.id for p in found] == ["a", "b"]

        await wait_for(written, 10, "the newest list written")
    finally:
        writer.cancel()
    found = await last.load()
    assert found is not None
    assert [p.api_key.get_secret_value() for p in found if p.api_key] == ["key-a", "key-b"]
    assert stat.S_IMODE(last.path.stat().st_mode) == 0o600


async def test_a_spoiled_copy_is_none_and_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    last = LastRead(tmp_path)
    last.path.write_text('{"version": 1, "printers": [')  # a write cut short by hand
    with caplog.at_level(logging.WARNING, logger="kybercore"):
        assert await last.load() is None
    assert "cannot start on the printers read last" in caplog.text
    assert "not valid JSON" in caplog.text
