"""How one printer's requests reach its Moonraker: HTTP on the shared pool, or JSON-RPC on
its live session; either is failed early, as unreachable, if Moonraker stops answering."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Mapping
from typing import Any, Final

import httpx

from kybercore.errors import (
    MoonrakerRpcError,
    PrinterError,
    PrinterTimeout,
    PrinterUnreachable,
)
from kybercore.moonraker.answers import malformed
from kybercore.moonraker.http import http_error, json_body
from kybercore.moonraker.reach import connect_problem
from kybercore.moonraker.refusals import refusal
from kybercore.moonraker.session import MoonrakerSession

# A slow answer is normal (G28, M109); a frozen Moonraker is not. While a request waits,
# Moonraker is probed every PROBE_AFTER s (a ping over the live session, else a small HTTP
# request); nothing back within PROBE_TIMEOUT s fails the request as unreachable (HTTP 503)
# instead of leaving it to wait minutes for its own timeout.
PROBE_AFTER: Final = 1.5
PROBE_TIMEOUT: Final = 2.0


class Channel:
    """One printer's way to its Moonraker (``http`` is shared and owned by the caller)."""

    def __init__(
        self,
        base_url: str,
        http: httpx.AsyncClient,
        headers: Mapping[str, str],
        session: MoonrakerSession,
        name: str,
    ) -> None:
        self._base_url = base_url
        self._http = http
        self._headers = dict(headers)
        self._session = session
        self._name = name

    async def request(self, method: str, path: str, **kwargs: Any) -> Any:
        """Send a request and unwrap Moonraker's ``{"result": ...}``."""
        body = json_body(await self.send(method, path, **kwargs), self._name)
        if not isinstance(body, dict) or "result" not in body:
            raise malformed(f"{method} {path}", "no 'result'", self._base_url, self._name)
        return body["result"]

    async def send(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """Send a request; a typed error unless Moonraker answers with a success."""
        url = self._base_url + path
        request = asyncio.ensure_future(
            self._http.request(method, url, headers=self._headers, **kwargs)
        )
        try:
            await self._wait_while_alive(request, method, path)
            response = await request
        except httpx.ConnectTimeout as exc:
            problem = connect_problem(exc, self._base_url, _connect_timeout(exc))
            raise PrinterTimeout(problem, printer=self._name) from exc
        except httpx.TimeoutException as exc:
            raise PrinterTimeout(
                f"Moonraker at {self._base_url} did not answer {method} {path} in time. "
                "Check the printer's network; retry later.",
                printer=self._name,
            ) from exc
        except httpx.TransportError as exc:
            problem = connect_problem(exc, self._base_url)
            raise PrinterUnreachable(problem, printer=self._name) from exc
        finally:
            if not request.done():
                request.cancel()
                with contextlib.suppress(asyncio.CancelledError, httpx.HTTPError):
                    await request
            elif not request.cancelled():
                request.exception()  # retrieved, as in rpc()
        if response.is_success:
            return response
        raise http_error(response, path, self._name)

    async def rpc(
        self, method: str, params: Mapping[str, Any] | None, timeout: float = 10.0
    ) -> Any:
        """A JSON-RPC call on the live session, failed early if Moonraker stops answering."""
        call = asyncio.ensure_future(self._session.call(method, params, timeout))
        try:
            await self._wait_while_alive(call, "RPC", method)
            return await call
        except MoonrakerRpcError as exc:
            refused = refusal(exc, method)
            if refused is None:
                raise
            raise refused from exc
        finally:
            if not call.done():
                call.cancel()
                with contextlib.suppress(asyncio.CancelledError, PrinterError):
                    await call
            elif not call.cancelled():
                # Done while this coroutine was being cancelled: its outcome is retrieved
                # here, or asyncio logs "Task exception was never retrieved" at collection.
                call.exception()

    async def _wait_while_alive(
        self, request: asyncio.Future[httpx.Response], method: str, path: str
    ) -> None:
        """Wait for ``request``; fail it as unreachable if Moonraker stops answering."""
        while not request.done():
            done, _ = await asyncio.wait({request}, timeout=PROBE_AFTER)
            if done:
                continue
            # A ping over the live session; without one, a fresh small HTTP request.
            alive = await self._session.alive(PROBE_TIMEOUT) if self._session.running else None
            if alive is None:
                alive = await self._http_alive()
            if alive is False and not request.done():
                raise PrinterUnreachable(
                    f"Moonraker at {self._base_url} stopped answering (nothing within "
                    f"{PROBE_TIMEOUT:g} s) while KyberCore waited for {method} {path}. "
                    "The printer may have run the command or not: check it before retrying.",
                    printer=self._name,
                )

    async def _http_alive(self) -> bool | None:
        """Whether ``/server/info`` answers within PROBE_TIMEOUT (None: it cannot tell)."""
        try:
            await self._http.get(
                self._base_url + "/server/info", headers=self._headers, timeout=PROBE_TIMEOUT
            )
        except httpx.TimeoutException:
            return False
        except httpx.HTTPError:
            return None
        return True


def _connect_timeout(exc: httpx.ConnectTimeout) -> float | None:
    """The connect timeout the failed request had, if httpx kept it."""
    try:
        value = exc.request.extensions.get("timeout", {}).get("connect")
    except RuntimeError:  # an exception raised without its request
        return None
    return float(value) if isinstance(value, (int, float)) else None
