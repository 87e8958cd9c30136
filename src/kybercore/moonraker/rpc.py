"""The JSON-RPC requests one Moonraker connection has in flight, and their answers."""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Callable, Mapping
from typing import Any

import orjson

from kybercore.errors import PrinterTimeout
from kybercore.moonraker.refusals import rpc_error

AnswerHook = Callable[[str, Any], None]
"""Called with (method, result) as a success is read, before its caller hears of it."""


class PendingCalls:
    """Request ids, the futures waiting on them, and the method each one called."""

    def __init__(self, printer: str) -> None:
        self._printer = printer
        self._ids = itertools.count(1)
        self._pending: dict[int, tuple[str, asyncio.Future[Any]]] = {}

    async def call(
        self,
        send: Callable[[bytes], None],
        method: str,
        params: Mapping[str, Any] | None,
        timeout: float,
    ) -> Any:
        """Send one request with ``send`` and return its ``result`` (or raise its error)."""
        req_id = next(self._ids)
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._pending[req_id] = (method, future)
        request: dict[str, Any] = {"jsonrpc": "2.0", "method": method, "id": req_id}
        if params is not None:
            request["params"] = dict(params)
        try:
            send(orjson.dumps(request))
            return await asyncio.wait_for(future, timeout)
        except TimeoutError as exc:
            raise PrinterTimeout(
                f"Moonraker did not answer '{method}' within {timeout:g} s",
                printer=self._printer,
            ) from exc
        finally:
            self._pending.pop(req_id, None)

    def answer(self, message: Mapping[str, Any], hook: AnswerHook) -> None:
        """Hand an answer (a message with ``result`` or ``error``) to the call it answers;
        answers to no call of ours, or of any shape, are ignored."""
        req_id = message.get("id")
        if not isinstance(req_id, int) or isinstance(req_id, bool):  # true == 1 in a dict
            return
        pending = self._pending.get(req_id)
        if pending is None or pending[1].done():
            return
        method, future = pending
        error = message.get("error")
        if error is None:
            result = message.get("result")
            hook(method, result)
            future.set_result(result)
        else:
            future.set_exception(rpc_error(error, method, self._printer))

    def fail_all(self, error: BaseException) -> None:
        """Fail every call in flight with ``error`` (the connection is gone)."""
        for _, future in self._pending.values():
            if not future.done():
                future.set_exception(error)
        self._pending.clear()
