"""KyberCore's HTTP face: REST endpoints, the browser WebSocket, and the dashboard files.

Thin on purpose: every endpoint hands its work to :class:`FleetService` and every error
becomes an HTTP answer in :func:`_kybercore_error` via :mod:`kybercore.api.errors`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import mimetypes
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated, Any, Final

import orjson
from fastapi import FastAPI, File, Form, Request, UploadFile, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException

from kybercore import __version__
from kybercore.api.errors import error_response, error_status, kybercore_error_response
from kybercore.api.models import (
    ActionName,
    ActionRequest,
    ActionResult,
    CheckResult,
    ErrorResponse,
    FileItem,
    FleetActionRequest,
    FleetActionResult,
    FleetCheckResult,
    GcodeRequest,
    Health,
    PrinterView,
)
from kybercore.api.security import (
    Access,
    GuardMiddleware,
    add_session_routes,
    require,
    websocket_identity,
)
from kybercore.core.validation import Verdict
from kybercore.errors import InvalidInput, KyberCoreError
from kybercore.fleet.actions import ActionOutcome, failed_outcome, reason_dict
from kybercore.fleet.service import FleetService
from kybercore.moonraker.client import new_http_client
from kybercore.registry.models import PrinterCreate, PrinterUpdate
from kybercore.registry.store import PrinterRegistry

log = logging.getLogger(__name__)

WEB_DIR: Final = Path(__file__).parent / "web"
HEARTBEAT_SECONDS: Final = 10.0
MAX_UPLOAD_BYTES: Final = 512 * 1024 * 1024
_ERRORS: Final[dict[int | str, dict[str, Any]]] = {
    status: {"model": ErrorResponse} for status in (404, 409, 422, 502, 503, 504)
}


VIEWER: Final = require("viewer")
OPERATOR: Final = require("operator")
ADMIN: Final = require("admin")


class ORJSONResponse(JSONResponse):
    """JSON answers serialized with orjson: the fleet view is the hot path."""

    def render(self, content: Any) -> bytes:
        return orjson.dumps(content)


def create_app(
    registry: PrinterRegistry, access: Access | None = None, **service_options: Any
) -> FastAPI:
    """The KyberCore ASGI app for the fleet in ``registry``; open access unless told."""

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        async with new_http_client() as http:
            service = FleetService(registry, http, **service_options)
            await service.start()
            app.state.service = service
            try:
                yield
            finally:
                await service.stop()

    app = FastAPI(
        title="KyberCore",
        version=__version__,
        description="Fleet manager for Klipper 3D printers through Moonraker.",
        lifespan=lifespan,
        default_response_class=ORJSONResponse,
    )
    app.state.access = access or Access("open", None)
    app.add_middleware(GuardMiddleware, max_body=MAX_UPLOAD_BYTES)
    app.add_exception_handler(KyberCoreError, _kybercore_error)  # type: ignore[arg-type]
    app.add_exception_handler(RequestValidationError, _validation_error)  # type: ignore[arg-type]
    app.add_exception_handler(StarletteHTTPException, _http_error)  # type: ignore[arg-type]
    app.add_exception_handler(Exception, _unexpected_error)
    _routes(app)
    add_session_routes(app)
    if WEB_DIR.is_dir():
        app.mount("/static", StaticFiles(directory=WEB_DIR), name="static")
    return app


def _service(request: Request | WebSocket) -> FleetService:
    service: FleetService = request.app.state.service
    return service


def _outcome(outcome: ActionOutcome) -> dict[str, Any]:
    if outcome.error is not None:
        status = error_status(outcome.error)[0]
    else:
        status = 201 if outcome.action == "upload" else 200
    return {
        "printer_id": outcome.printer_id,
        "action": outcome.action,
        "ok": outcome.ok,
        "status": status,
        "code": outcome.code,
        "message": outcome.message,
        "reasons": outcome.reasons,
    }


def _check(printer_id: str, action: str, verdict: Verdict) -> dict[str, Any]:
    return {
        "printer_id": printer_id,
        "action": action,
        "level": verdict.level,
        "reasons": [reason_dict(r) for r in verdict.reasons],
    }


def _routes(app: FastAPI) -> None:
    @app.get("/", include_in_schema=False)
    async def index() -> Response:
        return FileResponse(WEB_DIR / "fleet.html", headers={"Cache-Control": "no-cache"})

    @app.get("/api/health", response_model=Health, dependencies=[VIEWER])
    async def health(request: Request) -> dict[str, Any]:
        """Liveness plus a one-line picture of the fleet."""
        service = _service(request)
        views = service.views()
        return {
            "status": "ok",
            "version": __version__,
            "printers": len(views),
            "online": sum(v["connection"] == "online" for v in views),
            "browsers": service.hub.client_count,
            "config_error": service.config_error,
        }

    @app.get("/api/printers", responses={200: {"model": list[PrinterView]}}, dependencies=[VIEWER])
    async def list_printers(request: Request) -> Response:
        """Every printer: configuration fused with live state, from the live cache."""
        return Response(_service(request).fleet_json(), media_type="application/json")

    @app.post(
        "/api/printers",
        status_code=201,
        responses={201: {"model": PrinterView}, **_ERRORS},
        dependencies=[ADMIN],
    )
    async def add_printer(request: Request, new: PrinterCreate) -> Response:
        """Add a printer to printers.json and connect to it."""
        return ORJSONResponse(await _service(request).add_printer(new), status_code=201)

    @app.get(
        "/api/printers/{printer_id}",
        responses={200: {"model": PrinterView}, **_ERRORS},
        dependencies=[VIEWER],
    )
    async def get_printer(request: Request, printer_id: str) -> Response:
        """One printer, fused with its live state."""
        return ORJSONResponse(_service(request).view(printer_id))

    @app.patch(
        "/api/printers/{printer_id}",
        responses={200: {"model": PrinterView}, **_ERRORS},
        dependencies=[ADMIN],
    )
    async def edit_printer(request: Request, printer_id: str, patch: PrinterUpdate) -> Response:
        """Edit a printer (PATCH: omitted fields keep their value)."""
        return ORJSONResponse(await _service(request).update_printer(printer_id, patch))

    @app.delete(
        "/api/printers/{printer_id}", status_code=204, responses=_ERRORS, dependencies=[ADMIN]
    )
    async def remove_printer(request: Request, printer_id: str) -> Response:
        """Remove a printer from printers.json and disconnect from it."""
        await _service(request).remove_printer(printer_id)
        return Response(status_code=204)

    @app.post(
        "/api/printers/{printer_id}/actions/{action}",
        response_model=ActionResult,
        responses=_ERRORS,
        dependencies=[OPERATOR],
    )
    async def act(
        request: Request, printer_id: str, action: ActionName, body: ActionRequest | None = None
    ) -> dict[str, Any]:
        """Validate, then run an action on one printer; the real outcome or an error."""
        body = body or ActionRequest()
        outcome = await _service(request).act(
            printer_id, action, body.params(), force=body.force, confirm=body.confirm
        )
        return _outcome(outcome)

    @app.post(
        "/api/printers/{printer_id}/actions/{action}/check",
        response_model=CheckResult,
        responses=_ERRORS,
        dependencies=[VIEWER],
    )
    async def check(
        request: Request, printer_id: str, action: ActionName, body: ActionRequest | None = None
    ) -> dict[str, Any]:
        """Dry run: what validation says about the action now, without doing it."""
        body = body or ActionRequest()
        verdict = await _service(request).dry_run(printer_id, action, body.params(), body.force)
        return _check(printer_id, action, verdict)

    @app.post(
        "/api/printers/{printer_id}/gcode",
        response_model=ActionResult,
        responses=_ERRORS,
        dependencies=[OPERATOR],
    )
    async def gcode(request: Request, printer_id: str, body: GcodeRequest) -> dict[str, Any]:
        """Run G-code; answers when it has finished. Responses also stream over /ws."""
        outcome = await _service(request).act(
            printer_id, "gcode", {"script": body.script}, force=body.force, confirm=body.confirm
        )
        return _outcome(outcome)

    @app.get(
        "/api/printers/{printer_id}/files",
        response_model=list[FileItem],
        responses=_ERRORS,
        dependencies=[VIEWER],
    )
    async def files(request: Request, printer_id: str) -> list[dict[str, Any]]:
        """The printer's G-code files, newest first."""
        return await _service(request).files(printer_id)

    @app.delete(
        "/api/printers/{printer_id}/files",
        status_code=204,
        responses=_ERRORS,
        dependencies=[OPERATOR],
    )
    async def delete_file(request: Request, printer_id: str, path: str) -> Response:
        """Delete a G-code file (refused while it is being printed)."""
        await _service(request).delete_file(printer_id, _safe_path(path))
        return Response(status_code=204)

    @app.get("/api/printers/{printer_id}/files/metadata", responses=_ERRORS, dependencies=[VIEWER])
    async def file_metadata(request: Request, printer_id: str, filename: str) -> dict[str, Any]:
        """What the slicer wrote in a file's header, as Moonraker parsed it."""
        return await _service(request).file_metadata(printer_id, _safe_path(filename))

    @app.get("/api/printers/{printer_id}/files/thumbnail", responses=_ERRORS, dependencies=[VIEWER])
    async def thumbnail(request: Request, printer_id: str, path: str) -> Response:
        """A thumbnail image (path as given by a file's metadata, relative to gcodes/)."""
        path = _safe_path(path)
        if not path.lower().endswith((".png", ".jpg", ".jpeg")):
            raise InvalidInput("Only .png and .jpg thumbnails can be fetched.")
        content = await _service(request).client(printer_id).download(path)
        media = mimetypes.guess_type(path)[0] or "application/octet-stream"
        return Response(content, media_type=media, headers={"Cache-Control": "max-age=300"})

    @app.post(
        "/api/printers/{printer_id}/files",
        status_code=201,
        response_model=ActionResult,
        responses=_ERRORS,
        dependencies=[OPERATOR],
    )
    async def upload(
        request: Request,
        printer_id: str,
        file: Annotated[UploadFile, File(description="The G-code file.")],
        start: Annotated[bool, Form(description="Print it right after the upload.")] = False,
        confirm: Annotated[bool, Form(description="Go ahead despite warnings.")] = False,
    ) -> dict[str, Any]:
        """Upload a G-code file (checksummed); optionally validate it and start printing."""
        filename = _safe_path(file.filename or "")
        # The request size was checked before parsing (GuardMiddleware); the file itself
        # stays spooled on disk and is streamed on to Moonraker.
        outcome = await _service(request).upload(
            printer_id, filename, file.file, start=start, confirm=confirm
        )
        return _outcome(outcome)

    @app.post(
        "/api/fleet/actions/{action}",
        response_model=FleetActionResult,
        responses=_ERRORS,
        dependencies=[OPERATOR],
    )
    async def act_many(
        request: Request, action: ActionName, body: FleetActionRequest
    ) -> dict[str, Any]:
        """One action on several printers at once; one result per printer."""
        outcomes = await _service(request).act_many(
            body.printer_ids, action, body.params(), force=body.force, confirm=body.confirm
        )
        return {"results": [_outcome(o) for o in outcomes]}

    @app.post(
        "/api/fleet/actions/{action}/check",
        response_model=FleetCheckResult,
        responses=_ERRORS,
        dependencies=[VIEWER],
    )
    async def check_many(
        request: Request, action: ActionName, body: FleetActionRequest
    ) -> dict[str, Any]:
        """Dry run on several printers: what would happen on each."""
        service = _service(request)
        params = body.params()
        params.pop("printer_ids", None)

        async def one(printer_id: str) -> dict[str, Any]:
            try:
                verdict = await service.dry_run(printer_id, action, params, body.force)
            except KyberCoreError as exc:
                failed = failed_outcome(printer_id, action, exc)
                return {
                    "printer_id": printer_id,
                    "action": action,
                    "level": "block",
                    "reasons": failed.reasons
                    or [
                        {
                            "code": failed.code,
                            "level": "block",
                            "category": "state",
                            "en": failed.message,
                            "es": failed.message,
                        }
                    ],
                }
            return _check(printer_id, action, verdict)

        ids = list(dict.fromkeys(body.printer_ids))
        return {"results": list(await asyncio.gather(*(one(pid) for pid in ids)))}

    @app.websocket("/ws")
    async def browser_socket(websocket: WebSocket) -> None:
        """Snapshot, then coalesced deltas and events; send ``{"type": "console",
        "printers": [ids]}`` to receive those printers' G-code responses."""
        if websocket_identity(websocket) is None:
            # Before accept: the browser sees a failed handshake, no data leaks.
            await websocket.close(code=4401)
            return
        await websocket.accept()
        hub = _service(websocket).hub
        client = hub.connect()

        async def send() -> None:
            while True:
                try:
                    frame = await asyncio.wait_for(client.queue.get(), HEARTBEAT_SECONDS)
                except TimeoutError:
                    frame = orjson.dumps({"type": "heartbeat", "time": time.time()})
                await websocket.send_text(frame.decode())

        sender = asyncio.create_task(send())
        try:
            while True:
                message = await websocket.receive_json()
                if isinstance(message, dict) and message.get("type") == "console":
                    wanted = message.get("printers")
                    client.console = {str(p) for p in wanted} if isinstance(wanted, list) else set()
        except (WebSocketDisconnect, ValueError, RuntimeError):
            pass
        finally:
            hub.disconnect(client)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await sender


def _safe_path(path: str) -> str:
    """A file path relative to gcodes/: no absolute paths, no '..', no control characters."""
    parts = path.replace("\\", "/").split("/")
    if (
        not path
        or len(path) > 1024
        or path.startswith("/")
        or any(p in ("", ".", "..") for p in parts)
        or any(ord(c) < 32 for c in path)
    ):
        raise InvalidInput(
            f"'{path[:100]}' is not a valid file name: use a relative path without '..'."
        )
    return path


async def _kybercore_error(_request: Request, exc: KyberCoreError) -> Response:
    return kybercore_error_response(exc)


# Spanish for the validation errors people meet in forms; anything else gets the generic one.
_ES_FIELD_ERRORS: Final = {
    "missing": "Falta este campo.",
    "string_too_short": "Es demasiado corto.",
    "string_too_long": "Es demasiado largo.",
    "string_pattern_mismatch": "El formato no es válido.",
    "extra_forbidden": "Este campo no existe.",
    "json_invalid": "El JSON no es válido.",
    "greater_than": "El valor es demasiado pequeño.",
    "greater_than_equal": "El valor es demasiado pequeño.",
    "less_than": "El valor es demasiado grande.",
    "less_than_equal": "El valor es demasiado grande.",
    "too_long": "Hay demasiados elementos.",
}


async def _validation_error(_request: Request, exc: RequestValidationError) -> Response:
    # Built from locations and messages only: the input itself may hold an API key.
    fields = []
    for error in exc.errors():
        where = ".".join(str(part) for part in error.get("loc", ()) if part != "body") or "body"
        message = str(error.get("msg", "invalid"))
        kind = str(error.get("type", ""))
        spanish = _ES_FIELD_ERRORS.get(kind, f"El valor no es válido ({message}).")
        fields.append({"field": where, "en": message, "es": spanish})
    summary = "; ".join(f"{f['field']}: {f['en']}" for f in fields)
    return error_response(422, "invalid_input", f"Invalid request. {summary}", fields=fields)


async def _http_error(_request: Request, exc: StarletteHTTPException) -> Response:
    if exc.status_code == 400:
        # A body that does not parse (bad JSON, bad multipart) is invalid input like any other.
        return error_response(422, "invalid_input", f"Invalid request: {exc.detail}.")
    return error_response(exc.status_code, "http_error", str(exc.detail))


async def _unexpected_error(_request: Request, exc: Exception) -> Response:
    log.error("unexpected error", exc_info=exc)
    message = "Internal error in KyberCore; the server log has details."
    return error_response(500, "internal", message)
