"""KyberCore's HTTP face, the spec's ``fleet_controller``: the app factory that puts the
REST API, the browser WebSocket and the dashboard files together.

Thin on purpose: every endpoint hands its work to :class:`FleetService`, and every error
becomes an HTTP answer through :mod:`kybercore.api.errors`. The routes, one router per
resource:

- :mod:`kybercore.api.printers`: ``/api/printers``, add/read/edit/remove, actions, dry
  runs, G-code;
- :mod:`kybercore.api.files`: ``/api/printers/{id}/files``, list, metadata, thumbnails,
  upload, delete;
- :mod:`kybercore.api.temperatures`: ``/api/printers/{id}/temperatures``, the heaters'
  last half hour;
- :mod:`kybercore.api.fleet`: ``/api/health`` and bulk actions and dry runs;
- :mod:`kybercore.api.jobs`: ``/api/jobs``, ``/api/queue``, ``/api/gates`` and the plate
  gates (``/api/printers/{id}/clear|hold|release``): the job queue;
- :mod:`kybercore.api.history`: ``/api/history``, ``/api/history.csv``, ``/api/stats``:
  the ledger's job history and statistics; :mod:`kybercore.api.metrics`: ``/metrics``;
- :mod:`kybercore.api.notifications`: ``/api/notifications/...``: notification channels,
  their deliveries, the noise settings;
- :mod:`kybercore.api.session`: ``/api/session``, log in and out;
- :mod:`kybercore.api.audit`: ``/api/audit``, the audit log (admins);
- :mod:`kybercore.api.ws`: ``/ws``, the browser's live socket;
- :mod:`kybercore.api.docs`: ``/docs`` and ``/redoc``, the API's documentation;
- :mod:`kybercore.api.static`: ``/`` and ``/static/``, the dashboard, gzipped and
  cache-busted.

Every request passes :class:`~kybercore.api.guard.GuardMiddleware` first; every action
is recorded in the audit log by :class:`~kybercore.api.recorder.AuditMiddleware`.

The lifespan opens the queue's database (SQLite beside printers.json unless a URL is
given), then starts the fleet, the queue, the ledger and the notifications; it stops them
in the reverse order.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Coroutine, Mapping
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from pathlib import Path
from typing import Any, Final, Protocol

import httpx
from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from sqlalchemy.ext.asyncio import AsyncEngine
from starlette.exceptions import HTTPException as StarletteHTTPException

from kybercore import __version__
from kybercore.aio import cancel_and_wait
from kybercore.api import (
    audit,
    controls,
    discovery,
    files,
    fleet,
    history,
    jobs,
    metrics,
    notifications,
    printers,
    session,
    spools,
    temperatures,
    webcams,
    ws,
)
from kybercore.api.deps import ORJSONResponse
from kybercore.api.docs import add_docs
from kybercore.api.errors import (
    http_error_handler,
    kybercore_error_handler,
    unexpected_error_handler,
    validation_error_handler,
)
from kybercore.api.guard import GuardMiddleware
from kybercore.api.hosts import HostAllowlist
from kybercore.api.recorder import AuditMiddleware
from kybercore.api.security import Access
from kybercore.api.static import add_web
from kybercore.db import default_database_url, open_database
from kybercore.errors import KyberCoreError
from kybercore.fleet.service import FleetService
from kybercore.jobs.files import JobFiles
from kybercore.jobs.service import QueueService
from kybercore.jobs.store import JobStore
from kybercore.ledger.audit import AuditLog
from kybercore.ledger.metrics import Source
from kybercore.ledger.service import LedgerService
from kybercore.ledger.unwritten import UNWRITTEN
from kybercore.moonraker.http import new_http_client
from kybercore.notify.printers import FleetNotifyPrinters
from kybercore.notify.service import NotifyService
from kybercore.registry.store import PrinterRegistry

WEB_DIR: Final = Path(__file__).parent.parent / "web"
MAX_UPLOAD_BYTES: Final = 512 * 1024 * 1024


OnStarted = Callable[[FleetService, QueueService], Coroutine[Any, Any, None]]
"""Work to run once the fleet and the queue are up (``kybercore demo`` queues its jobs)."""


class Front(Protocol):
    """How a front on NATS (``kybercore front``, :mod:`kybercore.scale`) holds the fleet,
    the queue, the notifications and the metrics: its printers are held by workers, the
    database is shared with the other fronts, and the ledger is written by the workers."""

    def fleet(self, http: httpx.AsyncClient) -> FleetService:
        """The fleet as this front follows it."""

    def queue(
        self, fleet: FleetService, store: JobStore, folder: Path, options: Mapping[str, Any]
    ) -> QueueService:
        """The queue as this front serves it (``fleet`` started): its printers reached by
        command, its files shared with the other fronts; ``options`` as for
        :class:`QueueService`."""

    def notify(
        self,
        fleet: FleetService,
        queue: QueueService,
        engine: AsyncEngine,
        http: httpx.AsyncClient,
        options: Mapping[str, Any],
    ) -> NotifyService:
        """The notifications as this front serves them (not started: :meth:`serving`
        runs them); ``options`` as for :class:`NotifyService`."""

    def metrics(
        self, fleet: FleetService, engine: AsyncEngine
    ) -> AbstractAsyncContextManager[Source]:
        """While the app serves: the figures of ``/metrics`` (``fleet`` started), from the
        views it follows and the shared database."""

    def serving(
        self, fleet: FleetService, queue: QueueService, notify: NotifyService
    ) -> AbstractAsyncContextManager[None]:
        """While the app serves: share the queue's changes and the notifications' with the
        other fronts, and dispatch and notify whenever this front holds the dispatcher
        role."""


def create_app(
    registry: PrinterRegistry,
    access: Access | None = None,
    *,
    allowed_hosts: HostAllowlist | None = None,
    database_url: str | None = None,
    queue_options: Mapping[str, Any] | None = None,
    notify_options: Mapping[str, Any] | None = None,
    on_started: OnStarted | None = None,
    front: Front | None = None,
    **service_options: Any,
) -> FastAPI:
    """The KyberCore ASGI app for the fleet in ``registry``: open access and loopback names
    (plus any IP address) unless told; the queue's database at ``database_url`` (default:
    SQLite beside printers.json); ``queue_options`` go to :class:`QueueService`,
    ``notify_options`` to :class:`NotifyService` and ``service_options`` to
    :class:`FleetService`; ``front``: this process is a front on NATS (see :class:`Front`)."""
    folder = registry.path.parent

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        engine = await open_database(database_url or default_database_url(folder))
        app.state.engine = engine
        app.state.audit = AuditLog(engine)
        try:
            async with new_http_client() as http:
                if front is not None:
                    options = {"queue": queue_options or {}, "notify": notify_options or {}}
                    async with _front(app, front, http, folder, engine, options, on_started):
                        yield
                    return
                service = FleetService(registry, http, **service_options)
                queue = QueueService(
                    service, JobStore(engine), JobFiles(folder / "files"), **(queue_options or {})
                )
                app.state.service = service
                app.state.queue = queue
                # -- the ledger (issue 17): history, state timeline, /metrics --------
                ledger = LedgerService(service, engine, unwritten=folder / UNWRITTEN)
                app.state.metrics = ledger
                # -- notifications (issue 18): events to webhooks and Apprise ---------
                printers = FleetNotifyPrinters(service, http)
                notify = NotifyService(printers, queue, engine, http, **(notify_options or {}))
                app.state.notify = notify
                # ---------------------------------------------------------------------
                # What listens starts before the printers connect: at N = 5,000 the steps
                # awaited once 20,000 status updates a second flowed never ended, and the
                # HTTP port (opened after them) never opened. Each hears the connects.
                await queue.start()
                await ledger.start()
                await notify.start()
                started = None
                try:
                    await service.start()
                    if on_started is not None:
                        started = asyncio.create_task(on_started(service, queue))
                    yield
                finally:
                    await cancel_and_wait(started)
                    await notify.stop()
                    await ledger.stop()
                    await queue.stop()
                    await service.stop()
        finally:
            await app.state.audit.close()
            await engine.dispose()

    app = FastAPI(
        title="KyberCore",
        version=__version__,
        description="Fleet manager for Klipper 3D printers through Moonraker.",
        lifespan=lifespan,
        default_response_class=ORJSONResponse,
        docs_url=None,  # add_docs serves them without a CDN
        redoc_url=None,
        exception_handlers={
            KyberCoreError: kybercore_error_handler,
            RequestValidationError: validation_error_handler,
            StarletteHTTPException: http_error_handler,
            Exception: unexpected_error_handler,
        },
    )
    app.state.access = access or Access(None)
    app.add_middleware(
        GuardMiddleware,
        hosts=allowed_hosts or HostAllowlist(),
        upload_limit=MAX_UPLOAD_BYTES,
    )
    # Outside the guard: it records the answer the client really gets (a 413 included).
    app.add_middleware(AuditMiddleware)
    for module in (fleet, printers, files, temperatures, jobs, ws, session, audit):
        app.include_router(module.router)
    for module in (history, metrics):  # the ledger (issue 17)
        app.include_router(module.router)
    app.include_router(notifications.router)  # notifications (issue 18)
    app.include_router(controls.router)  # the printer page (issue 19)
    app.include_router(webcams.router)  # webcams: the printer page, the camera wall
    app.include_router(spools.router)  # Spoolman: which spool is on which printer
    app.include_router(discovery.router)  # "Find printers" (mDNS)
    add_docs(app)

    app.state.web = add_web(app, WEB_DIR)  # the dashboard: gzipped, cache-busted (issue 19)
    return app


@asynccontextmanager
async def _front(
    app: FastAPI,
    front: Front,
    http: httpx.AsyncClient,
    folder: Path,
    engine: AsyncEngine,
    options: Mapping[str, Mapping[str, Any]],
    on_started: OnStarted | None,
) -> AsyncIterator[None]:
    service = front.fleet(http)
    await service.start()
    try:
        queue = front.queue(service, JobStore(engine), folder / "files", options["queue"])
        notify = front.notify(service, queue, engine, http, options["notify"])
        app.state.service = service
        app.state.queue = queue
        app.state.notify = notify
        async with (
            front.metrics(service, engine) as figures,
            front.serving(service, queue, notify),
        ):
            app.state.metrics = figures
            started = asyncio.create_task(on_started(service, queue)) if on_started else None
            try:
                yield
            finally:
                await cancel_and_wait(started)
    finally:
        await service.stop()
