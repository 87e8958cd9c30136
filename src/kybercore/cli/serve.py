"""``kybercore serve``, ``demo`` and ``sim``: the commands that run servers and printers.

Their heavy imports (FastAPI, uvicorn, the simulator, the database) happen when they run,
not when the ``kybercore`` command starts.
"""

from __future__ import annotations

import asyncio
import gc
import ipaddress
import logging
import os
import shutil
import signal
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from kybercore.cli.options import (
    AllowedHosts,
    DatabaseUrl,
    HeatingBudget,
    Host,
    MdnsInterfaces,
    Port,
    PrintersFile,
    WsCompress,
)
from kybercore.cli.output import console, fail, print_table
from kybercore.errors import KyberCoreError
from kybercore.registry.store import PrinterRegistry, default_printers_path, write_printers

if TYPE_CHECKING:
    from kybercore.api.app import OnStarted
    from kybercore.api.hosts import HostAllowlist
    from kybercore.api.security import Access
    from kybercore.fleet.advisor import AdvisorConfig
    from kybercore.fleet.service import FleetService
    from kybercore.jobs.service import QueueService
    from kybercore.sim.stack import PrinterStack

log = logging.getLogger(__name__)
DEFAULT_HEATING_BUDGET = 3
YOUNG_COLLECTION = 20_000
"""Allocations between two young garbage collections once the fleet is connected."""


def serve(
    host: Host = "127.0.0.1",
    port: Port = 8000,
    printers_file: PrintersFile = None,
    allowed_host: AllowedHosts = None,
    mdns_interface: MdnsInterfaces = None,
    database_url: DatabaseUrl = None,
    heating_budget: HeatingBudget = DEFAULT_HEATING_BUDGET,
    ws_compress: WsCompress = False,
    advisor_url: Annotated[
        str | None,
        typer.Option(
            envvar="KYBERCORE_ADVISOR_URL",
            help="OpenAI-compatible chat API that may add warnings to actions (off if unset).",
        ),
    ] = None,
    advisor_model: Annotated[
        str, typer.Option(envvar="KYBERCORE_ADVISOR_MODEL", help="Model name for the advisor.")
    ] = "gpt-4o-mini",
    log_level: Annotated[
        str, typer.Option(help="debug, info, warning or error.", case_sensitive=False)
    ] = "info",
) -> None:
    """Serve the dashboard and API for the printers in printers.json.

    The advisor's API key is read from $KYBERCORE_ADVISOR_KEY (never a command-line flag,
    which would land in shell history).
    """
    from pydantic import SecretStr

    from kybercore.fleet.advisor import AdvisorConfig
    from kybercore.sim.stack import ensure_port_free

    path = printers_file or default_printers_path()
    advisor = None
    if advisor_url:
        key = os.environ.get("KYBERCORE_ADVISOR_KEY")
        advisor = AdvisorConfig(advisor_url, SecretStr(key) if key else None, advisor_model)
    try:
        hosts = _allowed_hosts(host, allowed_host or [])
        access = _access(path, host)
        ensure_port_free(port, host)
        registry = _open_registry(path)
        database = database_url or _default_database(path)
        _check_database(database)
    except KyberCoreError as exc:
        raise fail(exc.message) from None
    _run_server(
        registry,
        host,
        port,
        access,
        hosts,
        advisor=advisor,
        log_level=log_level,
        database_url=database,
        heating_budget=heating_budget,
        mdns_interfaces=mdns_interface or None,
        ws_compress=ws_compress,
    )


def demo(
    printers: Annotated[int, typer.Option(min=1, max=20, help="How many virtual printers.")] = 3,
    host: Host = "127.0.0.1",
    port: Port = 8000,
    folder: Annotated[
        Path | None, typer.Option("--dir", help="Where the demo keeps its printers' data.")
    ] = None,
    workers: Annotated[
        int,
        typer.Option(
            min=0,
            max=8,
            help="Run distributed: a local NATS server, this many ingest workers "
            "and a front (0: one process, as `serve`).",
        ),
    ] = 0,
) -> None:
    """Start virtual printers (real Klippy + Moonraker on a simulated MCU) and the dashboard."""
    from kybercore.sim.demo import demo_fleet, write_demo_printers
    from kybercore.sim.runtime import kybercore_home
    from kybercore.sim.stack import ensure_port_free

    folder = folder or kybercore_home() / "demo"
    try:
        ensure_port_free(port, host)
        _install_runtimes()
        with (
            console.status("Starting virtual printers…") as status,
            demo_fleet(
                folder, printers, forget_history=True, progress=lambda line: status.update(line)
            ) as stacks,
        ):
            path = folder / "printers.json"
            write_demo_printers(path, stacks)
            registry = _open_registry(path)
            access = _access(path, host)
            _forget_demo_queue(path)
            status.stop()
            _print_fleet(stacks)
            console.print(f"\n[bold green]KyberCore is up:[/bold green] http://{host}:{port}/")
            console.print(
                "A few jobs are queued: open the Queue view to watch them dispatch, and "
                "clear each printer's plate when its print is done."
            )
            console.print("Press Ctrl-C to stop the dashboard and every virtual printer.\n")
            if workers:
                from kybercore.cli.scale import demo_workers

                demo_workers(workers, host, port, path)
            else:
                _run_server(
                    registry, host, port, access, _allowed_hosts(host, []),
                    on_started=_queue_demo_jobs,
                )  # fmt: skip
    except KyberCoreError as exc:
        raise fail(exc.message) from None
    console.print("Stopped the dashboard and every virtual printer.")


def sim(
    printers: Annotated[int, typer.Option(min=1, max=20, help="How many virtual printers.")] = 3,
    base_port: Annotated[int, typer.Option(help="Moonraker port of the first printer.")] = 7125,
    folder: Annotated[Path | None, typer.Option("--dir", help="Data folder.")] = None,
) -> None:
    """Start virtual printers only, for Mainsail, Fluidd, curl or another KyberCore."""
    from kybercore.sim.demo import demo_fleet
    from kybercore.sim.runtime import kybercore_home

    folder = folder or kybercore_home() / "sim"
    try:
        _install_runtimes()
        with (
            console.status("Starting virtual printers…") as status,
            demo_fleet(
                folder, printers, base_port=base_port, progress=lambda line: status.update(line)
            ) as stacks,
        ):
            status.stop()
            _print_fleet(stacks)
            console.print("\nPress Ctrl-C to stop every virtual printer.")
            _wait_for_ctrl_c()
    except KyberCoreError as exc:
        raise fail(exc.message) from None
    console.print("Stopped every virtual printer.")


def _open_registry(path: Path) -> PrinterRegistry:
    """Read printers.json, creating an empty one if there is none; refuse a broken file."""
    registry = PrinterRegistry(path)
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_printers(path, [])
        console.print(
            f"Created an empty fleet in {path}. Add printers with `kybercore printers add`."
        )
    registry.reload()
    return registry


def _access(printers_file: Path, host: str) -> Access:
    """Open on loopback without tokens (until the first one is created); tokens otherwise;
    refuse what would be unsafe."""
    from kybercore.api.auth import SERVER_RECHECK_SECONDS, TokenStore, access_mode, tokens_path_for
    from kybercore.api.security import Access

    store = TokenStore(tokens_path_for(printers_file), recheck=SERVER_RECHECK_SECONDS)
    mode = access_mode(_is_loopback(host), store)
    if mode == "open":
        console.print(
            "Open access: listening on loopback and no token exists (tokens are required "
            "from the moment the first one is created)."
        )
    return Access(store, open_until_first_token=mode == "open")


def _allowed_hosts(host: str, names: list[str]) -> HostAllowlist:
    """The Host names to serve: the bound one, localhost, IPs and ``names`` (each may be a
    comma-separated list; $KYBERCORE_ALLOWED_HOSTS may use commas or spaces)."""
    from kybercore.api.hosts import HostAllowlist

    given = [name.strip() for item in names for name in item.split(",") if name.strip()]
    return HostAllowlist(bind=host, names=given)


def _default_database(printers_file: Path) -> str:
    from kybercore.db import default_database_url

    return default_database_url(printers_file.parent)


def _check_database(url: str) -> None:
    """Open the queue's database once (creating or upgrading it) before serving, so a bad
    URL or an unreachable server is one clear error line, not a failed start-up."""
    from kybercore.db import open_database

    async def check() -> None:
        engine = await open_database(url)
        await engine.dispose()

    asyncio.run(check())


def _forget_demo_queue(printers_file: Path) -> None:
    """Each demo starts from its few queued jobs: the last run's queue is forgotten (the
    demo's SQLite file beside printers.json and the job files; the printers' own job
    history goes with ``demo_fleet(forget_history=True)``)."""
    from sqlalchemy.engine import make_url

    database = make_url(_default_database(printers_file)).database
    if database:
        for suffix in ("", "-wal", "-shm", "-journal"):
            Path(database + suffix).unlink(missing_ok=True)
    shutil.rmtree(printers_file.parent / "files", ignore_errors=True)


async def _queue_demo_jobs(fleet: FleetService, queue: QueueService) -> None:
    """Queue the demo's jobs once its printers are ready (their limits read), so a
    newcomer sees copies dispatch, plates awaiting a clear and a job waiting with its
    reason. A job no demo printer could print (a fleet of one) is left out."""
    from kybercore.errors import KyberCoreError
    from kybercore.jobs.models import Requirements
    from kybercore.sim.demo import DEMO_JOBS, sample_files

    def ready(view: Any) -> bool:
        return bool(
            view["connection"] == "online"
            and view["klippy_state"] == "ready"
            and view["limits"] == "known"
        )

    for _ in range(240):
        if all(ready(view) for view in fleet.views()):
            break
        await asyncio.sleep(0.5)  # poll: printers come up over seconds, bounded above
    samples = dict(sample_files())
    for job in DEMO_JOBS:
        try:
            await queue.add_job(
                job.file,
                samples[job.file],
                quantity=job.copies,
                priority=0,
                not_before=None,
                requirements=Requirements(material=job.material),
                allow_mismatch=False,
                max_attempts=3,
                user="demo",
            )
        except KyberCoreError as exc:
            log.warning("demo job %s not queued: %s", job.file, exc.message)


def _run_server(
    registry: PrinterRegistry,
    host: str,
    port: int,
    access: Access,
    hosts: HostAllowlist,
    advisor: AdvisorConfig | None = None,
    log_level: str = "info",
    database_url: str | None = None,
    heating_budget: int = DEFAULT_HEATING_BUDGET,
    on_started: OnStarted | None = None,
    mdns_interfaces: list[str] | None = None,
    ws_compress: bool = False,
) -> None:
    from kybercore.api.app import create_app

    logging.basicConfig(
        level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    # The HTTP client logs every request at INFO; too chatty for a farm of printers.
    logging.getLogger("httpx").setLevel(logging.WARNING)
    app = create_app(
        registry,
        access,
        allowed_hosts=hosts,
        database_url=database_url,
        queue_options={"heating_budget": heating_budget or None},
        on_started=on_started,
        advisor=advisor,
        on_settled=freeze_heap,
        mdns_interfaces=mdns_interfaces,
    )
    run_http(app, host, port, ws_compress)


def run_http(app: Any, host: str, port: int, ws_compress: bool = False) -> None:
    """Serve ``app`` (the API, ``/ws`` and the dashboard) until stopped.

    WebSocket frames go out uncompressed unless ``ws_compress``, as Moonraker sends them:
    with permessage-deflate (which every browser asks for) each frame is compressed once
    per browser. Measured, side by side, at 1,000 printers with 10 browsers: 13-15 % more
    CPU per event (``bench/ingest_cost.py --deflate``), to save bandwidth a farm's network
    has; a dashboard over a slow link is the exception (``--ws-compress``)."""
    import uvicorn

    uvicorn.run(
        app,
        host=host,
        port=port,
        log_level="warning",
        ws="websockets-sansio",
        ws_per_message_deflate=ws_compress,
    )


def freeze_heap() -> None:
    """Move every object alive now out of the garbage collector's reach (``gc.freeze()``):
    once the fleet is connected, full collections then scan only what churns instead of
    every session and socket. Measured at 5,000 printers: the collector took 26 % of the
    CPU before. Frozen objects are still freed by reference count, so nothing long-lived
    may sit in a reference cycle (see ``Sessions._events_of``).

    Young collections then wait for :data:`YOUNG_COLLECTION` allocations instead of 700:
    every status update allocates dozens of containers (decoded JSON, a view per render)
    that live a tick or two, so at 700 the collector ran every few updates, promoted
    views still in use and paid for them again in the older generations (issue 20)."""
    gc.collect()
    gc.freeze()
    _, older, oldest = gc.get_threshold()
    gc.set_threshold(YOUNG_COLLECTION, older, oldest)


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _install_runtimes() -> None:
    from kybercore.sim.runtime import ensure_runtimes

    with console.status("Checking Moonraker and Klippy…") as status:
        ensure_runtimes(log=lambda line: status.update(line))


def _print_fleet(stacks: list[PrinterStack]) -> None:
    from rich.table import Table

    table = Table(title="Virtual printers")
    for column in ("printer", "Moonraker", "data"):
        table.add_column(column)
    for stack in stacks:
        table.add_row(stack.options.name, stack.url, str(stack.data_dir))
    print_table(table)


def _wait_for_ctrl_c() -> None:
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    stop.wait()
