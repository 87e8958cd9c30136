"""KyberCore on NATS as real processes for the tests: ingest workers and a front over a
real nats-server and real virtual printers, each stoppable, killable and pausable by PID."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.scale.broker import LocalServer
from kybercore.sim.stack import PrinterStack, free_port
from tests.helpers import KyberCoreServer, wait_until

SLOTS = 16
TTL = 3.0


class WorkerProcess:
    """One ``kybercore ingest`` subprocess."""

    def __init__(self, name: str, url: str, folder: Path, *extra_args: str) -> None:
        self.name = name
        self.folder = folder / name
        self.folder.mkdir(parents=True, exist_ok=True)
        command = [
            sys.executable, "-m", "kybercore", "ingest", "--nats", url, "--worker-id", name,
            "--slots", str(SLOTS), "--lease-ttl", str(TTL), "--dir", str(self.folder),
            *extra_args,
        ]  # fmt: skip
        with (self.folder / "worker.log").open("ab") as log:
            self.proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)

    @property
    def leases_log(self) -> Path:
        """Its own/drop log."""
        return self.folder / "leases.jsonl"

    def owned(self) -> set[int]:
        """The slots it owns now, replayed from its own/drop log (none once it is dead: a
        killed worker writes no drops)."""
        owned: set[int] = set()
        if self.proc.poll() is None and self.leases_log.exists():
            for line in self.leases_log.read_text().splitlines():
                event = json.loads(line)
                (owned.add if event["ev"] == "own" else owned.discard)(event["slot"])
        return owned

    def signal(self, sig: signal.Signals) -> None:
        """Send ``sig`` to it (by PID)."""
        os.kill(self.proc.pid, sig)

    def stop(self) -> None:
        """Continue it if paused, then stop it and wait."""
        if self.proc.poll() is None:
            self.signal(signal.SIGCONT)
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


SETTLE = 5 * (TTL + TTL / 3)
"""Ownership settling (start, rebalance): ~TTL + TTL/3, with 5× slack."""


@contextlib.contextmanager
def two_workers_and_a_front(
    stacks: list[PrinterStack], broker: LocalServer, folder: Path, database_url: str = ""
) -> Iterator[Cluster]:
    """``stacks`` as a fleet on NATS: w1 (started first), w2, their slots shared 8/8, and
    then a front importing their printers.json; stopped after. With
    ``database_url``, all three share that database (the workers keep the ledger)."""
    printers = [
        PrinterConfig(
            id=s.options.name, name=f"Printer {s.options.name[-1].upper()}", model="Virtual",
            location="Lab", tags=["test", s.options.name], moonraker_url=s.url,
        )
        for s in stacks
    ]  # fmt: skip
    write_printers(folder / "printers.json", printers)
    shared = ("--database-url", database_url) if database_url else ()
    front = KyberCoreServer(
        folder / "printers.json", free_port(), "--nats", broker.url, "--slots", str(SLOTS),
        "--lease-ttl", str(TTL), *shared, command="front",
    )  # fmt: skip
    cluster = Cluster(broker, folder, front, shared)
    try:
        w1 = cluster.worker("w1")
        wait_until(lambda: len(w1.owned()) == SLOTS, SETTLE, "w1 owns every slot")
        w2 = cluster.worker("w2")
        # Settled before the front starts: a printer it shows fresh is then reported by the
        # owner that takes its commands, not by w1 about to hand it to w2 (a command in
        # that handover gets 503 owner_moving, as it should, but a test would not expect it).
        wait_until(lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2, SETTLE, "8/8")
        front.start()
        yield cluster
    finally:
        cluster.close()


@contextlib.contextmanager
def fresh_cluster(
    stacks: list[PrinterStack], folder: Path, database_url: str = ""
) -> Iterator[Cluster]:
    """A nats-server of its own, then :func:`two_workers_and_a_front`; yields once every
    printer is fresh through the front. Everything is stopped after."""
    broker = LocalServer(folder / "nats")
    broker.start()
    try:
        with two_workers_and_a_front(stacks, broker, folder, database_url) as started:
            wait_until(lambda: started.all_fresh(len(stacks)), 60, "every printer fresh")
            yield started
    finally:
        broker.close()


class Cluster:
    """A broker, workers and one front; :meth:`close` stops what is still running."""

    def __init__(
        self,
        broker: LocalServer,
        folder: Path,
        front: KyberCoreServer,
        worker_args: tuple[str, ...] = (),
    ) -> None:
        self.broker = broker
        self.folder = folder
        self.front = front
        self.workers: dict[str, WorkerProcess] = {}
        self._worker_args = worker_args

    def worker(self, name: str, *extra_args: str) -> WorkerProcess:
        """Start the worker ``name`` (``extra_args``: ``--site``...)."""
        self.workers[name] = WorkerProcess(
            name, self.broker.url, self.folder, *self._worker_args, *extra_args
        )
        return self.workers[name]

    def views(self) -> list[dict[str, Any]]:
        """The fleet as the front shows it."""
        answer = httpx.get(f"{self.front.url}/api/printers", timeout=10)
        answer.raise_for_status()
        views: list[dict[str, Any]] = answer.json()
        return views

    def all_fresh(self, count: int) -> bool:
        """Whether ``count`` printers are online, ready and reported by a live owner."""
        views = self.views()
        fresh = [v for v in views if v["connection"] == "online" and v["klippy_state"] == "ready"]
        return len(fresh) == count

    def close(self) -> None:
        """Stop the front and every worker."""
        self.front.stop()
        for worker in self.workers.values():
            worker.stop()


def moonraker_sockets(stack: PrinterStack) -> int:
    """The WebSocket connections Moonraker holds (a KyberCore session is one)."""
    stats = httpx.get(f"{stack.url}/machine/proc_stats", timeout=10).json()["result"]
    count: int = stats["websocket_connections"]
    return count
