"""Answers of a shape no real Moonraker sends (a broken proxy, another server on the port, a
future version) are typed errors, never a KeyError or TypeError from deep in the client.

Unit-level fakes: an httpx mock transport answers every HTTP request, and a stand-in for
the session's call answers JSON-RPC; no traffic leaves the process.
"""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import httpx
import pytest

from kybercore.errors import KyberCoreError, MoonrakerRpcError
from kybercore.moonraker.client import MoonrakerClient

Call = Callable[[MoonrakerClient], Awaitable[Any]]

CALLS: dict[str, Call] = {
    "printer_info": lambda c: c.printer_info(),
    "server_info": lambda c: c.server_info(),
    "objects_list": lambda c: c.objects_list(),
    "objects_query": lambda c: c.objects_query({"extruder": None}),
    "files_list": lambda c: c.files_list(),
    "file_metadata": lambda c: c.file_metadata("a.gcode"),
    "file_thumbnails": lambda c: c.file_thumbnails("a.gcode"),
    "upload": lambda c: c.upload("a.gcode", b"G28\n"),
    "history_list": lambda c: c.history_list(),
    "history_totals": lambda c: c.history_totals(),
    "gcode_store": lambda c: c.gcode_store(),
    "webcams_list": lambda c: c.webcams_list(),
}

# Each a JSON body Moonraker's real answers never have: wrong types where objects, lists or
# fields are expected. A list of pairs and a dict where a list goes are the sneaky ones:
# dict() and list() would take them without a word.
ODD_RESULTS: list[Any] = [
    None,
    5,
    "text",
    [1, 2],
    [["a", "b"]],
    {"a": 1},
    {"objects": 5, "status": [1], "gcode_store": {"x": 1}, "webcams": "none"},
    {"objects": [1, {}], "status": {"extruder": 5}, "gcode_store": [1], "webcams": [None]},
]


def answering(body: Any) -> httpx.MockTransport:
    def handler(_request: httpx.Request) -> httpx.Response:
        return httpx.Response(200, content=json.dumps(body).encode())

    return httpx.MockTransport(handler)


@pytest.mark.parametrize("result", ODD_RESULTS, ids=[json.dumps(r) for r in ODD_RESULTS])
@pytest.mark.parametrize("name", sorted(CALLS))
async def test_odd_http_answers_are_typed_errors(name: str, result: Any) -> None:
    # Moonraker wraps answers in {"result": ...}, except the upload's.
    body = result if name == "upload" else {"result": result}
    async with httpx.AsyncClient(transport=answering(body)) as http:
        client = MoonrakerClient("http://127.0.0.1:7125", http, name="p")
        answer = await attempt(CALLS[name], client)
    if isinstance(answer, MoonrakerRpcError):
        assert "unexpected answer" in answer.message, answer.message
        assert answer.message.startswith("p: ")
    elif not isinstance(answer, KyberCoreError):
        # Accepted: then it has the type the method promises, all the way down.
        assert_shape(name, answer)


async def attempt(call: Call, client: MoonrakerClient) -> Any:
    """The call's answer, or the typed error it raised (anything else fails the test)."""
    try:
        return await call(client)
    except KyberCoreError as exc:
        return exc


def assert_shape(name: str, answer: Any) -> None:
    if name in ("files_list", "file_thumbnails", "gcode_store", "webcams_list"):
        assert isinstance(answer, list)
        assert all(isinstance(item, dict) for item in answer), answer
    elif name == "objects_list":
        assert isinstance(answer, list)
        assert all(isinstance(item, str) for item in answer), answer
    elif name == "objects_query":
        assert isinstance(answer, dict)
        assert all(isinstance(fields, dict) for fields in answer.values()), answer
    else:
        assert isinstance(answer, dict), answer


@pytest.mark.parametrize("result", ODD_RESULTS, ids=[json.dumps(r) for r in ODD_RESULTS])
async def test_odd_json_rpc_answers_are_typed_errors(
    result: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    async def call(
        method: str, params: Mapping[str, Any] | None = None, timeout: float = 10
    ) -> Any:
        return result

    async with httpx.AsyncClient(transport=answering({"result": result})) as http:
        client = MoonrakerClient("http://127.0.0.1:7125", http, name="p")
        monkeypatch.setattr(type(client.session), "connected", property(lambda _self: True))
        monkeypatch.setattr(client.session, "call", call)
        for name in ("objects_query", "file_metadata"):
            answer = await attempt(CALLS[name], client)
            if not isinstance(answer, KyberCoreError):
                assert_shape(name, answer)
