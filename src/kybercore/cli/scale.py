"""``kybercore ingest`` and ``kybercore front``: KyberCore across processes on NATS, and
``kybercore demo --workers N`` to see it in one command.

``kybercore serve`` (one process, no broker) stays the default; these are for a fleet that
outgrows one process or one machine (see the README's "Scale-out on NATS").
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
from collections.abc import Coroutine, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from kybercore.cli.options import AllowedHosts, DatabaseUrl, Host, Port, PrintersFile, WsCompress
from kybercore.cli.output import console, fail
from kybercore.errors import KyberCoreError
from kybercore.registry.models import SITE_PATTERN, PrinterConfig

if TYPE_CHECKING:
    from kybercore.api.app import OnStarted

NatsUrl = Annotated[
    str,
    typer.Option(
        "--nats",
        envvar="KYBERCORE_NATS",
        help="The NATS server (nats://host:4222), JetStream on; a cluster's, separated by "
        "commas; a site's leaf node, then its hub's JetStream domain: "
        "nats://site-leaf:4222?js_domain=hub.",
    ),
]
Slots = Annotated[
    int,
    typer.Option(min=1, max=1024, help="Slots the fleet is split into; the same in every process."),
]
LogLevel = Annotated[str, typer.Option(help="debug, info, warning or error.")]


def ingest(
    nats_url: NatsUrl,
    worker_id: Annotated[
        str | None, typer.Option(help="This worker's name (default: host name and PID).")
    ] = None,
    slots: Slots = 64,
    site: Annotated[
        str,
        typer.Option(
            help="Hold only the printers of this site (their 'site' field); default: the "
            "printers without one.",
            show_default=False,
        ),
    ] = "",
    lease_ttl: Annotated[
        float, typer.Option(min=1.0, help="Seconds a lease lasts without renewal.")
    ] = 6.0,
    grace: Annotated[
        float, typer.Option(min=0.0, help="Seconds a lost slot's sessions stay open.")
    ] = 30.0,
    folder: Annotated[
        Path | None, typer.Option("--dir", help="Where the worker writes its leases log.")
    ] = None,
    database_url: Annotated[
        str | None,
        typer.Option(
            "--database-url",
            envvar="KYBERCORE_DATABASE_URL",
            help="The fronts' database (PostgreSQL): the worker writes the job history and "
            "state timeline of its printers there. Without it, no ledger is kept.",
            show_default=False,
        ),
    ] = None,
    local_leases: Annotated[
        bool,
        typer.Option(
            "--local-leases",
            help="Keep this site's leases in the JetStream of the NATS server given, a site's "
            "leaf node with JetStream of its own (its --nats names the hub's domain for the "
            "rest): a cut between the site and the hub then leaves its printers held.",
        ),
    ] = False,
    log_level: LogLevel = "info",
) -> None:
    """Run an ingest worker: own a share of the printers, hold their Moonraker sessions,
    publish their views to NATS and run their actions."""
    from kybercore.sim.runtime import kybercore_home

    name = worker_id or f"{socket.gethostname()}-{os.getpid()}"
    where = folder or kybercore_home() / "workers" / name
    _logging(log_level)
    try:
        if not re.fullmatch(SITE_PATTERN, site):
            raise fail(
                f"'{site}' is not a site name: lowercase letters, digits, '-' and '_', up to "
                "32 characters, starting with a letter or digit."
            )
        where.mkdir(parents=True, exist_ok=True)
        _run_loop(
            _ingest(
                nats_url, name, slots, site, lease_ttl, grace, where, database_url, local_leases
            )
        )
    except KyberCoreError as exc:
        raise fail(exc.message) from None
    except OSError as exc:
        raise _unreachable(nats_url, exc) from None


def _unreachable(url: str, exc: OSError) -> typer.Exit:
    return fail(f"Cannot reach NATS at {url} ({exc}). Is nats-server -js running there?")


def _run_loop(main: Coroutine[Any, Any, None]) -> None:
    """Run ``main`` on uvloop where it is installed (everywhere but Windows), as uvicorn
    runs ``serve`` and ``front``: a worker's loop carries every frame of its printers, and
    on stock asyncio's loop, written in Python, a worker cost 5-8 % more CPU."""
    try:
        import uvloop
    except ImportError:
        asyncio.run(main)
    else:
        uvloop.run(main)


async def _ingest(
    url: str, name: str, slots: int, site: str, ttl: float, grace: float, folder: Path,
    database: str | None, local_leases: bool,
) -> None:  # fmt: skip
    from kybercore.moonraker.http import new_http_client
    from kybercore.scale.broker import connect
    from kybercore.scale.worker import Worker

    nc = await connect(url, f"kybercore-ingest-{name}")
    async with new_http_client() as http:
        worker = Worker(
            nc,
            name,
            http,
            url=url,
            slots=slots,
            ttl=ttl,
            folder=folder,
            site=site,
            grace=grace,
            database=database,
            local_leases=local_leases,
        )
        await worker.start()
        where = f" for site '{site}'" if site else ""
        logging.getLogger(__name__).info("worker %s up on %s%s", name, url, where)
        await _until_signal()
        await worker.stop()
    await nc.close()


def front(
    nats_url: NatsUrl,
    host: Host = "127.0.0.1",
    port: Port = 8000,
    printers_file: PrintersFile = None,
    allowed_host: AllowedHosts = None,
    database_url: DatabaseUrl = None,
    slots: Slots = 64,
    front_id: Annotated[
        str | None,
        typer.Option("--front-id", help="This front's name (default: host name and PID)."),
    ] = None,
    lease_ttl: Annotated[
        float,
        typer.Option(
            min=1.0,
            help="Seconds the dispatcher role lasts without renewal (one front "
            "dispatches the queue; another takes over within about this).",
        ),
    ] = 6.0,
    ws_compress: WsCompress = False,
    log_level: LogLevel = "info",
) -> None:
    """Serve the dashboard, the API and the job queue for a fleet held by ingest workers on
    NATS (no printer sockets here). printers.json is imported into an empty registry on
    NATS. Several fronts share one database (--database-url, PostgreSQL); one of them
    dispatches the queue at a time."""
    from kybercore.registry.store import default_printers_path

    serve_front(
        nats_url, host, port, printers_file or default_printers_path(),
        allowed_host=allowed_host or [], database_url=database_url, slots=slots,
        name=front_id or f"{socket.gethostname()}-{os.getpid()}", lease_ttl=lease_ttl,
        log_level=log_level, ws_compress=ws_compress,
    )  # fmt: skip


def serve_front(
    nats_url: str,
    host: str,
    port: int,
    path: Path,
    *,
    allowed_host: list[str],
    database_url: str | None,
    slots: int,
    name: str,
    lease_ttl: float,
    log_level: str,
    on_started: OnStarted | None = None,
    ws_compress: bool = False,
) -> None:
    """``kybercore front``'s work, also the distributed demo's (which queues its jobs
    ``on_started``)."""
    from kybercore.api.app import create_app
    from kybercore.cli.serve import _access, _allowed_hosts, _default_database, run_http
    from kybercore.registry.store import PrinterRegistry
    from kybercore.scale.broker import reachable
    from kybercore.scale.front_queue import Front
    from kybercore.sim.stack import ensure_port_free

    try:
        asyncio.run(reachable(nats_url))
    except OSError as exc:
        raise _unreachable(nats_url, exc) from None
    try:
        ensure_port_free(port, host)
        hosts = _allowed_hosts(host, allowed_host)
        access = _access(path, host)
    except KyberCoreError as exc:
        raise fail(exc.message) from None
    _logging(log_level)
    app = create_app(
        PrinterRegistry(path),
        access,
        allowed_hosts=hosts,
        database_url=database_url or _default_database(path),
        on_started=on_started,
        front=Front(nats_url, slots, path, name, lease_ttl),
    )
    run_http(app, host, port, ws_compress)


def export_printers(
    nats_url: NatsUrl,
    out: Annotated[Path, typer.Option("--out", help="The printers.json to write.")],
    with_keys: Annotated[
        bool, typer.Option(help="Include the Moonraker API keys (the file is 0600 either way).")
    ] = False,
) -> None:
    """Write the registry on NATS to a printers.json (a backup, or a way back to ``serve``).
    The file is replaced atomically; the old one is kept as .bak."""
    from kybercore.registry.store import write_printers

    try:
        printers = asyncio.run(_registry_printers(nats_url, with_keys))
    except OSError as exc:
        raise _unreachable(nats_url, exc) from None
    if not with_keys:
        keyed = [p.id for p in printers if p.api_key is not None]
        printers = [p.model_copy(update={"api_key": None}) for p in printers]
        if keyed:
            console.print(
                f"{len(keyed)} printers have an API key, not written ({', '.join(keyed)}); "
                "--with-keys writes them."
            )
    try:
        write_printers(out, printers)
    except OSError as exc:
        raise fail(f"Cannot write {out} ({exc}).") from None
    console.print(f"{len(printers)} printers written to {out}.")


async def _registry_printers(url: str, with_keys: bool) -> list[PrinterConfig]:
    from kybercore.scale.broker import connect
    from kybercore.scale.registry import KvRegistry

    nc = await connect(url, "kybercore-export")
    try:
        registry = KvRegistry(read_keys=with_keys)
        await registry.open(nc)
        return await registry.printers()
    finally:
        await nc.close()


def demo_workers(workers: int, host: str, port: int, printers_file: Path) -> None:
    """The demo's distributed form: a local nats-server, ``workers`` ingest workers (child
    processes) and a front in this process, over the demo's printers.json."""
    from kybercore.cli.serve import _queue_demo_jobs
    from kybercore.scale.broker import LocalServer

    # Each demo starts from its printers.json: the last run's registry and leases go.
    shutil.rmtree(printers_file.parent / "nats", ignore_errors=True)
    broker = LocalServer(printers_file.parent / "nats")
    broker.start()
    console.print(f"NATS (JetStream) at {broker.url}; {workers} ingest workers.")
    try:
        with _workers(broker.url, workers, printers_file.parent):
            serve_front(
                broker.url, host, port, printers_file, allowed_host=[], database_url=None,
                slots=64, name="demo-front", lease_ttl=6.0, log_level="warning",
                on_started=_queue_demo_jobs,
            )  # fmt: skip
    finally:
        broker.stop()


@contextlib.contextmanager
def _workers(url: str, count: int, folder: Path) -> Iterator[None]:
    procs = [
        subprocess.Popen(
            [
                sys.executable, "-m", "kybercore", "ingest", "--nats", url,
                "--worker-id", f"w{n}", "--dir", str(folder / "workers" / f"w{n}"),
                "--log-level", "warning",
            ]
        )
        for n in range(1, count + 1)
    ]  # fmt: skip
    try:
        yield
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


async def _until_signal() -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    await stop.wait()


def _logging(level: str) -> None:
    logging.basicConfig(
        level=level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    logging.getLogger("httpx").setLevel(logging.WARNING)
    # Alembic 1.20 announces each of its plugins at import, a worker's first lines otherwise.
    logging.getLogger("alembic.runtime.plugins").setLevel(logging.WARNING)
