"""Every action taken over HTTP goes into the audit log (:mod:`kybercore.ledger.audit`):
recorded here once for every route, so a new route is audited without a line of its own.

A request is an action when it changes something (not GET/HEAD/OPTIONS), reached a route
(the guard's refusals never do) and is not a dry run (``.../check``). The row says who
(the caller's token name and role, ``local`` on an open server, ``anonymous``), what (the
action named from the route, :data:`ACTIONS`), to which printer or job (its path), with
what (path, query and JSON body parameters, secrets redacted), how it ended (``ok`` or the
error's code from the answer) and from where (client address, request id). A bulk action
is one row per printer with that printer's own outcome, all with one request id.

The row is written before the answer's last byte leaves: a client that has its answer
finds its action in the log. A route may add what the middleware cannot see (an upload's
file name in a multipart body, who logged in) with :func:`note`.
"""

from __future__ import annotations

import logging
import re
import uuid
from collections.abc import Mapping
from typing import Any, Final

import orjson
from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from kybercore.api.auth import Identity
from kybercore.api.guard import SAFE_METHODS
from kybercore.db.outage import said
from kybercore.errors import DatabaseUnavailable
from kybercore.ledger.audit import AuditEntry, AuditLog

log = logging.getLogger(__name__)

ACTIONS: Final = {
    ("POST", "/api/printers"): "printer.add",
    ("PATCH", "/api/printers/{printer_id}"): "printer.edit",
    ("DELETE", "/api/printers/{printer_id}"): "printer.remove",
    ("POST", "/api/printers/{printer_id}/actions/{action}"): "printer.{action}",
    ("POST", "/api/printers/{printer_id}/gcode"): "printer.gcode",
    ("POST", "/api/fleet/actions/{action}"): "printer.{action}",
    ("POST", "/api/printers/{printer_id}/files"): "file.upload",
    ("DELETE", "/api/printers/{printer_id}/files"): "file.delete",
    ("POST", "/api/printers/{printer_id}/clear"): "plate.clear",
    ("POST", "/api/printers/{printer_id}/hold"): "printer.hold",
    ("POST", "/api/printers/{printer_id}/release"): "printer.release",
    ("POST", "/api/jobs"): "job.create",
    ("PATCH", "/api/jobs/{job_id}"): "job.edit",
    ("DELETE", "/api/jobs/{job_id}"): "job.cancel",
    ("POST", "/api/jobs/{job_id}/move"): "job.move",
    ("POST", "/api/jobs/{job_id}/requeue"): "job.requeue",
    ("POST", "/api/queue"): "queue.change",
    ("POST", "/api/notifications/channels"): "channel.add",
    ("PATCH", "/api/notifications/channels/{channel_id}"): "channel.edit",
    ("DELETE", "/api/notifications/channels/{channel_id}"): "channel.remove",
    ("POST", "/api/notifications/channels/{channel_id}/test"): "channel.test",
    ("PUT", "/api/notifications/settings"): "notify.settings",
    ("POST", "/api/session"): "session.login",
    ("DELETE", "/api/session"): "session.logout",
}
"""Action names by (method, route). A route missing here is still recorded, under its
function's name."""

BULK_ROUTE: Final = "/api/fleet/actions/{action}"
TARGETS: Final = {"printer_id": "printer", "job_id": "job", "channel_id": "channel"}
"""Path parameters that name an action's target, and the kind of target."""
REQUEST_ID_HEADER: Final = "x-request-id"
_REQUEST_ID: Final = re.compile(r"[A-Za-z0-9._:-]{1,64}")
_CAPTURE_LIMIT: Final = 8 * 1024 * 1024
"""JSON bodies (request and answer) are kept up to this size to read parameters and
outcomes; a bulk answer for 10,000 printers is ~2 MB."""
_NOTE: Final = "kybercore_audit"


def note(connection: HTTPConnection, **fields: Any) -> None:
    """Add to the audit row of this request what only the route knows: ``params`` (merged
    into the parameters), ``actor`` and ``role``, ``action``, ``target``."""
    noted: dict[str, Any] = connection.scope.setdefault("state", {}).setdefault(_NOTE, {})
    params = {**noted.get("params", {}), **fields.pop("params", {})}
    noted.update(fields, params=params)


class AuditMiddleware:
    """Records every action that reached a route, once its answer is known."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] in SAFE_METHODS:
            await self.app(scope, receive, send)
            return
        audit_log: AuditLog | None = getattr(scope["app"].state, "audit", None)
        if audit_log is None:  # an app without a database: nothing to record into
            await self.app(scope, receive, send)
            return
        await _Recording(scope, audit_log).run(self.app, receive, send)


class _Recording:
    """One write request on its way through: its body and answer seen, its row written."""

    def __init__(self, scope: Scope, audit_log: AuditLog) -> None:
        self.scope = scope
        self.audit_log = audit_log
        connection = HTTPConnection(scope)
        asked = connection.headers.get(REQUEST_ID_HEADER, "")
        self.request_id = asked if _REQUEST_ID.fullmatch(asked) else uuid.uuid4().hex
        identity: Identity | None = scope["app"].state.access.identify(
            connection.headers, connection.cookies
        )
        self.actor, self.role = (identity.name, identity.role) if identity else ("anonymous", "")
        self.client = scope["client"][0] if scope.get("client") else ""
        json_body = connection.headers.get("content-type", "").startswith("application/json")
        self.request_body: bytearray | None = bytearray() if json_body else None
        self.status = 0
        self.answer: bytearray | None = None

    async def run(self, app: ASGIApp, receive: Receive, send: Send) -> None:
        async def receive_seen() -> Message:
            message = await receive()
            if message["type"] == "http.request" and self.request_body is not None:
                self.request_body += message.get("body", b"")
                if len(self.request_body) > _CAPTURE_LIMIT:
                    self.request_body = None
            return message

        recorded = False

        async def send_seen(message: Message) -> None:
            nonlocal recorded
            if message["type"] == "http.response.start":
                self.status = message["status"]
                headers = message.get("headers", [])
                json_answer = any(
                    name.lower() == b"content-type" and value.startswith(b"application/json")
                    for name, value in headers
                )
                self.answer = bytearray() if json_answer else None
                message["headers"] = [*headers, (b"x-request-id", self.request_id.encode())]
            elif message["type"] == "http.response.body":
                if self.answer is not None:
                    self.answer += message.get("body", b"")
                    if len(self.answer) > _CAPTURE_LIMIT:
                        self.answer = None
                if not message.get("more_body", False) and not recorded:
                    recorded = True
                    await self._record()
            await send(message)

        try:
            await app(self.scope, receive_seen, send_seen)
        except BaseException:
            if not recorded:
                self.status = self.status or 500
                await self._record(outcome="internal_error")
            raise

    async def _record(self, outcome: str | None = None) -> None:
        route = self.scope.get("route")
        path = getattr(route, "path", None)
        if not isinstance(path, str) or path.endswith("/check") or self.status == 405:
            return  # not a route (the guard refused it, 404, 405), or a dry run
        try:
            await self.audit_log.record(*self._entries(path, outcome))
        except DatabaseUnavailable as exc:
            log.warning(
                "The audit row of %s %s waits until the database answers (%s); the action "
                "ran, and its answer goes out", self.scope["method"], path, said(exc),
            )  # fmt: skip
        except Exception:
            # The action happened whatever the log says: the answer still goes out.
            log.exception("Could not write the audit row of %s %s", self.scope["method"], path)

    def _entries(self, path: str, outcome: str | None) -> list[AuditEntry]:
        method = self.scope["method"]
        path_params: dict[str, Any] = dict(self.scope.get("path_params", {}))
        name = ACTIONS.get((method, path)) or str(getattr(self.scope.get("route"), "name", path))
        if "{action}" in name:
            name = name.replace("{action}", str(path_params.pop("action", "")))
        target = ""
        for param, kind in TARGETS.items():
            if param in path_params:
                target = f"{kind}:{path_params.pop(param)}"
                break
        params: dict[str, Any] = {**path_params, **dict(HTTPConnection(self.scope).query_params)}
        body = _json(self.request_body)
        if isinstance(body, Mapping):
            params.update(body)
        elif body is not None:
            params["body"] = body
        noted: dict[str, Any] = self.scope.get("state", {}).get(_NOTE, {})
        params.update(noted.get("params", {}))
        answer = _json(self.answer)
        if not target and self.status < 300 and isinstance(answer, Mapping) and "id" in answer:
            target = f"{name.split('.')[0]}:{answer['id']}"  # what it created: printer:x, job:7
        base = AuditEntry(
            actor=noted.get("actor", self.actor),
            role=noted.get("role", self.role),
            action=noted.get("action", name),
            target=noted.get("target", target),
            params=params,
            outcome=outcome or self._outcome(),
            client=self.client,
            request_id=self.request_id,
        )
        if path == BULK_ROUTE and self.status == 200:
            return _per_printer(base, answer)
        return [base]

    def _outcome(self) -> str:
        if self.status < 400:
            return "ok"
        answer = _json(self.answer)
        error = answer.get("error") if isinstance(answer, Mapping) else None
        code = error.get("code") if isinstance(error, Mapping) else None
        return str(code) if code else f"http_{self.status}"


def _per_printer(base: AuditEntry, answer: Any) -> list[AuditEntry]:
    """A bulk action's row for each printer, with that printer's outcome."""
    results = answer.get("results") if isinstance(answer, Mapping) else None
    if not isinstance(results, list):
        return [base]
    params = {k: v for k, v in base.params.items() if k != "printer_ids"}
    params["bulk"] = len(results)
    return [
        AuditEntry(
            actor=base.actor,
            role=base.role,
            action=base.action,
            target=f"printer:{result.get('printer_id', '')}",
            params=params,
            outcome="ok" if result.get("ok") else str(result.get("code") or "error"),
            client=base.client,
            request_id=base.request_id,
        )
        for result in results
        if isinstance(result, Mapping)
    ]


def _json(data: bytearray | None) -> Any:
    if not data:
        return None
    try:
        return orjson.loads(data)
    except orjson.JSONDecodeError:
        return None
