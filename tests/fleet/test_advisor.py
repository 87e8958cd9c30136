"""The optional advisor, against a local stand-in for an OpenAI-compatible chat API.

``FakeChatCompletionsServer`` is NOT an AI: it is a tiny HTTP server on 127.0.0.1 (ephemeral
port) that records each request and answers the way it is told to: with warnings, with junk,
with an error, or not at all for 5 s.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Any

import httpx
import pytest
from pydantic import SecretStr

from kybercore.core.messages import Reason
from kybercore.core.validation import PrinterFacts, Verdict, validate
from kybercore.fleet.advisor import (
    SYSTEM_PROMPT,
    AdvisorConfig,
    advise,
    chat_completions_url,
    combine,
    parse_answer,
)

API_KEY = "sk-test-DO-NOT-LOG-3f9a"
CUT_WITHIN = 7.5
"""Promise: the advisor is cut at its 1.5 s budget. Idle: 1.50 s (5x); bench/promises.py
measures it. That it was cut, not answered, the reason's code says exactly."""
PRINTER = PrinterFacts(
    "online", "ready", "standby", "Prusa MK4", (250.0, 210.0, 220.0), None, 0.4, "PLA", 290, 120
)
FILE_META = {
    "slicer": "PrusaSlicer",
    "object_height": 20.0,
    "nozzle_diameter": 0.4,
    "filament_type": "PLA",
    "first_layer_extr_temp": 215.0,
    "thumbnails": [{"width": 32, "height": 32, "size": 118, "relative_path": ".thumbs/a.png"}],
}
WARNINGS_ANSWER = {
    "warnings": [
        {"en": "Fan at 100% on the first layer may lift the corners.",
         "es": "El ventilador al 100 % en la primera capa puede levantar las esquinas."},
        {"en": "   ", "es": "texto sin inglés"},
        "not an object",
    ]
}  # fmt: skip


def chat_response(content: str) -> bytes:
    """A chat-completions response body carrying ``content`` as the assistant's message."""
    return json.dumps(
        {
            "id": "chatcmpl-stand-in",
            "object": "chat.completion",
            "model": "stand-in",
            "choices": [
                {
                    "index": 0,
                    "message": {"role": "assistant", "content": content},
                    "finish_reason": "stop",
                }
            ],
        }
    ).encode()


@dataclass
class Recorded:
    method: str
    path: str
    headers: dict[str, str]
    body: dict[str, Any]


@dataclass
class FakeChatCompletionsServer:
    """Stand-in for an advisor endpoint; ``mode`` says how it answers."""

    mode: str = "warnings"  # warnings | fenced | malformed | error | stall
    stall_seconds: float = 5.0
    requests: list[Recorded] = field(default_factory=list)
    port: int = 0
    _server: asyncio.Server | None = None
    _handlers: set[asyncio.Task[None]] = field(default_factory=set)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    async def __aenter__(self) -> FakeChatCompletionsServer:
        self._server = await asyncio.start_server(self._handle, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._server is not None
        self._server.close()
        for task in list(self._handlers):  # a stalled handler would otherwise outlive the test
            task.cancel()
        await asyncio.gather(*self._handlers, return_exceptions=True)
        await self._server.wait_closed()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._handlers.add(task)
        try:
            request_line = (await reader.readline()).decode()
            method, path, _ = request_line.split(" ", 2)
            headers: dict[str, str] = {}
            while (line := (await reader.readline()).decode().strip()) != "":
                name, _, value = line.partition(":")
                headers[name.strip().lower()] = value.strip()
            body = await reader.readexactly(int(headers.get("content-length", "0")))
            self.requests.append(Recorded(method, path, headers, json.loads(body)))
            status, payload = await self._answer()
            writer.write(
                f"HTTP/1.1 {status}\r\nContent-Type: application/json\r\n"
                f"Content-Length: {len(payload)}\r\nConnection: close\r\n\r\n".encode()
                + payload
            )
            await writer.drain()
        finally:
            writer.close()
            self._handlers.discard(task)

    async def _answer(self) -> tuple[str, bytes]:
        if self.mode == "stall":
            await asyncio.sleep(self.stall_seconds)  # stand-in: simulates a peer that stalls
        if self.mode == "error":
            return "500 Internal Server Error", b'{"error": {"message": "overloaded"}}'
        if self.mode == "malformed":
            return "200 OK", chat_response('{"warnings": [ this is not json')
        if self.mode == "fenced":
            return "200 OK", chat_response("```json\n" + json.dumps(WARNINGS_ANSWER) + "\n```")
        return "200 OK", chat_response(json.dumps(WARNINGS_ANSWER))


@pytest.fixture
async def http() -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient() as client:
        yield client


@contextlib.asynccontextmanager
async def stand_in(mode: str) -> AsyncIterator[tuple[FakeChatCompletionsServer, AdvisorConfig]]:
    async with FakeChatCompletionsServer(mode=mode) as server:
        yield server, AdvisorConfig(url=server.url, api_key=SecretStr(API_KEY), model="m-1")


async def test_warnings_are_added_and_the_request_is_well_formed(
    http: httpx.AsyncClient, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    async with stand_in("warnings") as (server, cfg):
        params = {"filename": "cube.gcode"}
        reasons = await advise(http, cfg, "start", PRINTER, params, FILE_META)
    [reason] = reasons  # the two malformed items are skipped
    assert (reason.code, reason.level, reason.category) == ("advisor_warning", "warn", "advisor")
    assert reason.en == "Advisor: Fan at 100% on the first layer may lift the corners."
    assert reason.es.startswith("Asesor: El ventilador")
    [request] = server.requests
    assert (request.method, request.path) == ("POST", "/v1/chat/completions")
    assert request.headers["authorization"] == f"Bearer {API_KEY}"
    assert request.body["model"] == "m-1"
    system, user = request.body["messages"]
    assert system == {"role": "system", "content": SYSTEM_PROMPT}
    assert "only ADD warnings" in system["content"]
    facts = json.loads(user["content"])
    assert facts["action"] == "start"
    assert facts["params"] == params
    assert facts["printer"]["nozzle_diameter"] == 0.4
    assert facts["file"]["first_layer_extr_temp"] == 215.0
    assert "thumbnails" not in facts["file"]
    assert "skipped" in caplog.text
    assert API_KEY not in caplog.text


async def test_fenced_json_answer_is_understood(http: httpx.AsyncClient) -> None:
    async with stand_in("fenced") as (_, cfg):
        reasons = await advise(http, cfg, "gcode", PRINTER, {"script": "G28"}, None)
    assert [r.code for r in reasons] == ["advisor_warning"]


async def test_malformed_answer_is_ignored_and_logged(
    http: httpx.AsyncClient, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    async with stand_in("malformed") as (server, cfg):
        reasons = await advise(http, cfg, "start", PRINTER, {"filename": "a.gcode"}, FILE_META)
    assert len(server.requests) == 1
    [reason] = reasons
    assert (reason.code, reason.level, reason.category) == (
        "advisor_unavailable",
        "warn",
        "advisor",
    )
    assert "rules" in reason.en
    assert "reglas" in reason.es
    assert "unreadable" in caplog.text
    assert API_KEY not in caplog.text


async def test_stalled_advisor_is_cut_at_the_budget(
    http: httpx.AsyncClient, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    async with stand_in("stall") as (server, cfg):
        server.stall_seconds = 60  # far beyond the bound below: only a cut ends the wait
        assert cfg.budget_seconds == 1.5  # the default budget, really waited for
        began = time.monotonic()
        reasons = await advise(http, cfg, "start", PRINTER, {"filename": "a.gcode"}, FILE_META)
        elapsed = time.monotonic() - began
    assert len(server.requests) == 1  # it was asked, and it did not answer in time
    assert 1.5 <= elapsed < CUT_WITHIN
    [reason] = reasons
    assert reason.code == "advisor_unavailable"
    assert "1.5 s" in reason.en
    assert "1,5 s" in reason.es
    assert API_KEY not in caplog.text


async def test_http_error_and_unreachable_advisor_fall_back_to_the_rules(
    http: httpx.AsyncClient,
) -> None:
    async with stand_in("error") as (_, cfg):
        reasons = await advise(http, cfg, "start", PRINTER, {}, None)
    assert [r.code for r in reasons] == ["advisor_unavailable"]
    assert "HTTP 500" in reasons[0].en
    # The stand-in is closed now: nothing listens on its port any more.
    reasons = await advise(http, cfg, "start", PRINTER, {}, None)
    assert [r.code for r in reasons] == ["advisor_unavailable"]
    assert "could not be reached" in reasons[0].en


async def test_no_advisor_or_an_action_it_does_not_review_sends_nothing(
    http: httpx.AsyncClient,
) -> None:
    assert await advise(http, None, "start", PRINTER, {}, None) == ()
    async with stand_in("warnings") as (server, cfg):
        for action in ("emergency_stop", "pause", "cancel", "firmware_restart"):
            assert await advise(http, cfg, action, PRINTER, {}, None) == ()
    assert server.requests == []


async def test_without_a_key_no_authorization_header_is_sent(http: httpx.AsyncClient) -> None:
    async with FakeChatCompletionsServer() as server:
        cfg = AdvisorConfig(url=server.url + "/v1/")
        await advise(http, cfg, "set_temperature", PRINTER, {"extruder": 200}, None)
    assert "authorization" not in server.requests[0].headers
    assert server.requests[0].path == "/v1/chat/completions"


def test_the_key_is_hidden_in_the_config_repr() -> None:
    cfg = AdvisorConfig(url="http://127.0.0.1:1", api_key=SecretStr(API_KEY))
    assert API_KEY not in repr(cfg)
    assert API_KEY not in str(cfg)


@pytest.mark.parametrize(
    ("url", "endpoint"),
    [
        ("http://h:1", "http://h:1/v1/chat/completions"),
        ("http://h:1/", "http://h:1/v1/chat/completions"),
        ("http://h:1/v1", "http://h:1/v1/chat/completions"),
        ("http://h:1/api/v1/chat/completions", "http://h:1/api/v1/chat/completions"),
    ],
)
def test_chat_completions_url(url: str, endpoint: str) -> None:
    assert chat_completions_url(url) == endpoint


@pytest.mark.parametrize(
    "raw",
    [
        b"not json",
        b"{}",
        b'{"choices": []}',
        chat_response("plain prose, no JSON"),
        chat_response('{"warnings": "none"}'),
        chat_response('["warnings"]'),
        json.dumps({"choices": [{"message": {"content": None}}]}).encode(),
    ],
)
def test_parse_answer_rejects_what_it_cannot_read(raw: bytes) -> None:
    assert parse_answer(raw) is None


def test_parse_answer_caps_count_and_length() -> None:
    many = {"warnings": [{"en": "x" * 1000, "es": "y"} for _ in range(20)]}
    found = parse_answer(chat_response(json.dumps(many)))
    assert found is not None
    assert len(found) == 5
    assert len(found[0][0]) == 300
    assert parse_answer(chat_response('{"warnings": []}')) == []


def test_combine_never_blocks_and_never_unblocks() -> None:
    advisor_warning = Reason("advisor_warning", "warn", "advisor", "Advisor: a", "Asesor: a")
    rogue = Reason("advisor_warning", "block", "state", "Advisor: stop", "Asesor: alto")

    ok = validate("home", PRINTER)
    assert combine(ok, ()).level == "ok"
    assert combine(ok, (advisor_warning,)).level == "warn"
    raised = combine(ok, (rogue,))
    assert raised.level == "warn"
    assert raised.reasons[-1].category == "advisor"

    blocked = validate("pause", PRINTER)
    assert blocked.blocked
    combined = combine(blocked, (advisor_warning,))
    assert combined.blocked
    assert combined.reasons == (*blocked.reasons, advisor_warning)
    assert combine(Verdict.of([]), ()).reasons == ()
