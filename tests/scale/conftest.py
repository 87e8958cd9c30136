"""Fixtures of the scale-out tests: clusters of real processes (a broker of their own, two
workers, a front), one shared by a module's tests, or one with a real PostgreSQL."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from kybercore.sim.stack import PrinterStack
from tests.db.postgres import PostgresServer, PostgresUnavailable
from tests.jobs.conftest import postgres_server, unavailable
from tests.scale.cluster import Cluster, fresh_cluster

__all__ = ["postgres_server"]


@pytest.fixture
def shared_database(postgres_server: PostgresServer | PostgresUnavailable) -> Iterator[str]:
    """A fresh database on the suite's PostgreSQL, for every process of one cluster."""
    if isinstance(postgres_server, PostgresUnavailable):
        unavailable(str(postgres_server))
        raise AssertionError("unreachable")
    url = postgres_server.create_database()
    yield url
    postgres_server.recycle(url)


@pytest.fixture
def shared_cluster(
    fleet_stacks: list[PrinterStack], tmp_path: Path, shared_database: str
) -> Iterator[Cluster]:
    """Two workers and a front on a broker of their own, sharing ``shared_database``."""
    with fresh_cluster(fleet_stacks, tmp_path, shared_database) as started:
        yield started


@pytest.fixture(scope="module")
def cluster(
    fleet_stacks: list[PrinterStack], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Cluster]:
    """A cluster without a database, shared by the tests of one module (a module needing
    its own per test defines ``cluster`` itself)."""
    with fresh_cluster(fleet_stacks, tmp_path_factory.mktemp("cluster")) as started:
        yield started
