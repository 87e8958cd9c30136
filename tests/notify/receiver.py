"""A loopback HTTP receiver for the notification tests: a real server (uvicorn + Starlette)
on 127.0.0.1 that records every request, as a webhook receiver, an Apprise ``json://`` or
``form://`` target, or a webcam would see them.

It can be told to answer errors first (:meth:`Receiver.fail_next`), to refuse some requests
(:meth:`Receiver.refuse`), to hang (:meth:`Receiver.hold`), to serve fixed content
(:meth:`Receiver.serve`, for a webcam's snapshot), and it can be stopped and started again
on the same port (a receiver that is down, then back).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import orjson
import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

from kybercore.sim.stack import free_port

HANG = "hang"
"""Content for :meth:`Receiver.serve` that never answers (a webcam that hangs)."""


@dataclass(frozen=True)
class Received:
    """One request as it arrived, and the status it was answered with."""

    method: str
    path: str
    headers: dict[str, str]
    """Lower-case names."""
    body: bytes
    status: int
    at: float

    def json(self) -> Any:
        """The body, parsed as JSON."""
        return orjson.loads(self.body)

    @property
    def accepted(self) -> bool:
        """Answered with a 2xx."""
        return 200 <= self.status < 300


class Receiver:
    """See the module docstring. ``requests`` holds every request, in arrival order."""

    def __init__(self) -> None:
        self.port = free_port()
        self.requests: list[Received] = []
        self._failures: list[int] = []
        self._refuse: Callable[[Received], bool] = lambda _r: False
        self._content: dict[str, tuple[bytes | str, str]] = {}
        self._server: uvicorn.Server | None = None
        self._task: asyncio.Task[None] | None = None
        self._released = asyncio.Event()
        self._holding = False
        self.held = 0
        """POSTs that arrived while holding (:meth:`hold`)."""

    def url(self, path: str = "/hook") -> str:
        """This receiver's URL for ``path``."""
        return f"http://127.0.0.1:{self.port}{path}"

    @property
    def accepted(self) -> list[Received]:
        """The requests answered with a 2xx, in arrival order."""
        return [r for r in self.requests if r.accepted]

    def fail_next(self, count: int, status: int = 500) -> None:
        """Answer the next ``count`` POSTs with ``status``."""
        self._failures = [status] * count

    def refuse(self, when: Callable[[Received], bool]) -> None:
        """Answer 500 to every POST for which ``when`` is true (from now on)."""
        self._refuse = when

    def hold(self) -> None:
        """Keep every POST waiting, unanswered, until :meth:`stop` (a receiver that hangs
        while KyberCore stops)."""
        self._holding = True

    def serve(self, path: str, content: bytes | str, content_type: str = "image/jpeg") -> None:
        """Answer GET ``path`` with ``content`` (:data:`HANG`: never answer)."""
        self._content[path] = (content, content_type)

    def unserve(self, path: str) -> None:
        """GET ``path`` answers 404 again."""
        self._content.pop(path, None)

    async def start(self) -> None:
        """Serve on 127.0.0.1 at :attr:`port` until :meth:`stop`."""
        app = Starlette(routes=[Route("/{path:path}", self._handle, methods=["GET", "POST"])])
        config = uvicorn.Config(
            app, host="127.0.0.1", port=self.port, log_level="warning", lifespan="off",
            timeout_graceful_shutdown=1,
        )  # fmt: skip
        self._released.clear()
        self._server = uvicorn.Server(config)
        self._task = asyncio.create_task(self._server.serve())
        while not self._server.started:
            if self._task.done():
                self._task.result()
            await asyncio.sleep(0.01)  # stand-in: uvicorn offers no started event

    async def stop(self) -> None:
        """Stop serving (connections are refused until :meth:`start`); requests kept."""
        self._released.set()
        self._holding = False
        if self._server is not None:
            self._server.should_exit = True
        if self._task is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._task, 10)
        self._server = self._task = None

    async def _handle(self, request: Request) -> Response:
        path = "/" + request.path_params["path"]
        body = await request.body()
        headers = {k.lower(): v for k, v in request.headers.items()}
        if request.method == "GET":
            return await self._serve(path, headers)
        if self._holding:
            self.held += 1
            await self._released.wait()
            return Response("shutting down", status_code=503)
        status = 200
        if self._failures:
            status = self._failures.pop(0)
        seen = Received(request.method, path, headers, body, status, time.monotonic())
        if status == 200 and self._refuse(seen):
            status = 500
            seen = Received(request.method, path, headers, body, status, seen.at)
        self.requests.append(seen)
        text = "ok" if status < 300 else "receiver says no"
        return Response(text, status_code=status, media_type="text/plain")

    async def _serve(self, path: str, headers: dict[str, str]) -> Response:
        content, content_type = self._content.get(path, (b"", ""))
        status = 200 if path in self._content else 404
        self.requests.append(Received("GET", path, headers, b"", status, time.monotonic()))
        if status == 404:
            return Response("no such thing", status_code=404)
        if content == HANG:
            await self._released.wait()
            return Response(status_code=503)
        return Response(content, media_type=content_type)
