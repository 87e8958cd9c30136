"""KyberCore distributed for the benchmark: a nats-server, K ``kybercore ingest`` workers and
one ``kybercore front``, each a process of its own, stopped by PID afterwards.

:func:`kybercore_cluster` stands in for ``kybercore serve`` in :mod:`bench.fleet_scale`
(``--workers K``): the same load generator, browsers and fleet reads point at the front.
Every process's CPU is read separately, so the figures say what one worker and one front
cost per 1,000 events.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Final

import httpx

from bench import procs

# kybercore ships no py.typed marker; mypy sees it as an untyped installed package.
from kybercore.scale.broker import LocalServer  # type: ignore[import-untyped, unused-ignore]

SLOTS: Final = 64
LEASE_TTL: Final = 6.0


@contextlib.asynccontextmanager
async def kybercore_cluster(
    printers_file: Path,
    work: Path,
    port: int,
    workers: int,
    src: Path | None,
    timeout: float,
) -> AsyncIterator[tuple[dict[str, int], httpx.AsyncClient]]:
    """The cluster up; yields ``{role: pid}`` (``front``, ``w1``…, ``nats``) and an HTTP
    client on the front."""
    broker = LocalServer(work / "nats")
    await asyncio.to_thread(broker.start)
    env = {**os.environ, "PYTHONPATH": str(src)} if src else None
    common = ["--nats", broker.url, "--slots", str(SLOTS)]
    try:
        async with contextlib.AsyncExitStack() as stack:
            pids: dict[str, int] = {"nats": broker.pid or 0}
            for n in range(1, workers + 1):
                name = f"w{n}"
                log = stack.enter_context((work / f"{name}.log").open("wb"))
                args = ["-m", "kybercore", "ingest", *common, "--worker-id", name]
                args += ["--lease-ttl", str(LEASE_TTL), "--dir", str(work / name)]
                args += ["--log-level", "warning"]
                process = await stack.enter_async_context(procs.child(*args, log=log, env=env))
                pids[name] = process.pid
            log = stack.enter_context((work / "front.log").open("wb"))
            args = ["-m", "kybercore", "front", *common, "--port", str(port)]
            args += ["--printers-file", str(printers_file), "--log-level", "warning"]
            front = await stack.enter_async_context(procs.child(*args, log=log, env=env))
            pids["front"] = front.pid
            http = await stack.enter_async_context(
                httpx.AsyncClient(
                    base_url=f"http://127.0.0.1:{port}", trust_env=False, timeout=timeout
                )
            )
            yield pids, http
    finally:
        await asyncio.to_thread(broker.close)
