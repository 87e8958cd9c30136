"""Fixtures of the scale-out tests: clusters of real processes (a broker of their own, two
workers, a front), one shared by a module's tests, or one with a real PostgreSQL."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from kybercore.sim.stack import PrinterStack, free_port
from tests.helpers import KyberCoreServer
from tests.scale.cluster import SLOTS, TTL, Cluster, fresh_cluster


@pytest.fixture
def shared_cluster(
    fleet_stacks: list[PrinterStack], tmp_path: Path, postgres_database: str
) -> Iterator[Cluster]:
    """Two workers and a front on a broker of their own, sharing ``postgres_database``."""
    with fresh_cluster(fleet_stacks, tmp_path, postgres_database) as started:
        yield started


@pytest.fixture
def front_b(
    shared_cluster: Cluster, tmp_path: Path, postgres_database: str
) -> Iterator[KyberCoreServer]:
    """Another front on ``shared_cluster``'s broker and database, with its own disk: started
    after the cluster's (which holds the roles first), stopped after the test."""
    folder = tmp_path / "front-b"
    folder.mkdir()
    shutil.copy(shared_cluster.folder / "printers.json", folder / "printers.json")
    front = KyberCoreServer(
        folder / "printers.json", free_port(), "--nats", shared_cluster.broker.url,
        "--slots", str(SLOTS), "--database-url", postgres_database, "--front-id", "front-b",
        "--lease-ttl", str(TTL), command="front",
    )  # fmt: skip
    front.start()
    yield front
    front.stop()


@pytest.fixture(scope="module")
def cluster(
    fleet_stacks: list[PrinterStack], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Cluster]:
    """A cluster without a database, shared by the tests of one module (a module needing
    its own per test defines ``cluster`` itself)."""
    with fresh_cluster(fleet_stacks, tmp_path_factory.mktemp("cluster")) as started:
        yield started
