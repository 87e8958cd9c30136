"""An ingest worker's ledger when its database does not answer as the worker starts
(:mod:`kybercore.scale.worker_ledger`): restarted, it holds its printers and starts the
ledger once the database answers; on its first start it stops, saying why. Real
nats-server, PostgreSQL (reached through a :class:`~tests.cable.Cable` the test cuts),
workers, front and printers."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from sqlalchemy import func, select

from kybercore.db import open_database, transaction
from kybercore.ledger.tables import printer_states
from kybercore.ledger.unwritten import UNWRITTEN
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.scale.broker import LocalServer
from kybercore.sim.stack import PrinterStack, free_port
from tests.cable import to_database
from tests.helpers import KyberCoreServer, wait_until
from tests.scale.cluster import SETTLE, SLOTS, TTL, Cluster

BACK_WITHIN = 60.0
"""The worker tries its database every 5 s; a busy machine is slower."""


def scalar(database_url: str, query: Any) -> Any:
    """``query``'s one value, read from the database at ``database_url``."""

    async def read() -> Any:
        engine = await open_database(database_url)
        try:
            return await transaction(engine, lambda conn: conn.scalar(query), write=False)
        finally:
            await engine.dispose()

    return asyncio.run(read())


def states_since(database_url: str, since: float) -> int:
    """How many state intervals of the printers began after ``since`` (epoch seconds)."""
    return int(
        scalar(database_url, select(func.count()).where(printer_states.c.started_at > since))
    )


def test_a_worker_restarted_while_its_database_is_away_holds_its_printers_and_ledger_later(
    nats_server: LocalServer,
    fleet_stacks: list[PrinterStack],
    tmp_path: Path,
    postgres_database: str,
) -> None:
    printers = [PrinterConfig(id=s.options.name, name=s.options.name, moonraker_url=s.url)
                for s in fleet_stacks]  # fmt: skip
    write_printers(tmp_path / "printers.json", printers)
    cable, through_cable = to_database(postgres_database)
    front = KyberCoreServer(
        tmp_path / "printers.json", free_port(), "--nats", nats_server.url,
        "--slots", str(SLOTS), "--lease-ttl", str(TTL), "--database-url", postgres_database,
        command="front",
    )  # fmt: skip
    front.start()
    cluster = Cluster(nats_server, tmp_path, front, ("--database-url", through_cable))
    try:
        worker = cluster.worker("w1")
        wait_until(lambda: cluster.all_fresh(len(fleet_stacks)), 60, "every printer fresh")
        cable.cut()
        worker.stop()
        stopped = time.time()
        kept = worker.folder / UNWRITTEN
        assert kept.exists(), "the state changes its stop could not write are kept"
        again = cluster.worker("w1")
        wait_until(lambda: len(again.owned()) == SLOTS, SETTLE, "w1 owns every slot again")
        wait_until(lambda: cluster.all_fresh(len(fleet_stacks)), 60, "every printer fresh again")
        said = (again.folder / "worker.log").read_text()
        assert "cannot open the ledger's database" in said
        assert "the printers are held meanwhile" in said
        mended = time.time()
        cable.mend()
        # Its ledger starts: the printers' states are written from then on.
        wait_until(
            lambda: states_since(postgres_database, mended) >= len(fleet_stacks), BACK_WITHIN,
            "the restarted worker's ledger to write the printers' states",
        )  # fmt: skip
        assert "can open the ledger's database again" in (again.folder / "worker.log").read_text()
        # ... having first written what its stop could not: its intervals end at the stop,
        # not when it heard its printers again.
        assert not kept.exists()
        states = printer_states.c
        ended = select(func.max(states.ended_at)).where(states.started_at < stopped)
        assert scalar(postgres_database, ended) <= stopped
    finally:
        cluster.close()
        cable.close()


def test_a_worker_whose_database_does_not_answer_at_its_first_start_stops_saying_so(
    nats_server: LocalServer, tmp_path: Path
) -> None:
    nowhere = f"postgresql+asyncpg://kybercore@127.0.0.1:{free_port()}/kybercore"
    done = subprocess.run(
        [sys.executable, "-m", "kybercore", "ingest", "--nats", nats_server.url,
         "--dir", str(tmp_path), "--database-url", nowhere],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode != 0
    assert "Cannot open the database postgresql+asyncpg://kybercore@127.0.0.1" in done.stderr
    assert "Traceback" not in done.stderr
    leases = tmp_path / "leases.jsonl"
    assert not leases.exists() or leases.read_text() == ""  # no slot was claimed
