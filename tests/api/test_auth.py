"""Access control: tokens with roles, the browser session, origins, headers, and secrets
kept out of every answer, frame and log line."""

from __future__ import annotations

import json
import stat
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
import websockets
from typer.testing import CliRunner

from kybercore.api.auth import COOKIE, TokenStore, access_mode, tokens_path_for
from kybercore.cli.main import app
from kybercore.errors import ConfigError, InvalidInput
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.sim.stack import PrinterStack, free_port
from tests.helpers import KyberCoreServer

MOONRAKER_KEY = "moonraker-key-that-must-never-leak-0123456789"


def test_tokens_are_stored_hashed_and_checked_by_role(tmp_path: Path) -> None:
    store = TokenStore(tmp_path / "tokens.json")
    record, token = store.create("alice", "operator")
    assert token.startswith("kc_")
    text = (tmp_path / "tokens.json").read_text()
    assert token not in text
    assert record.sha256 in text
    assert stat.S_IMODE((tmp_path / "tokens.json").stat().st_mode) == 0o600
    identity = store.identify(token)
    assert identity is not None
    assert (identity.name, identity.role) == ("alice", "operator")
    assert identity.may("viewer")
    assert identity.may("operator")
    assert not identity.may("admin")
    assert store.identify(token + "x") is None
    store.revoke(record.id)
    assert store.identify(token) is None
    with pytest.raises(InvalidInput, match="Unknown role"):
        store.create("bob", "root")
    with pytest.raises(InvalidInput, match="No token"):
        store.revoke("t_missing")


def test_open_only_on_loopback_without_tokens(tmp_path: Path) -> None:
    store = TokenStore(tmp_path / "tokens.json")
    assert access_mode(True, store) == "open"
    with pytest.raises(ConfigError, match="will not listen beyond loopback"):
        access_mode(False, store)
    store.create("admin", "admin")
    assert access_mode(False, store) == "tokens"
    assert access_mode(True, store) == "tokens"


def test_serve_refuses_to_listen_beyond_loopback_without_tokens(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app, ["serve", "--host", "0.0.0.0", "--printers-file", str(tmp_path / "p.json")]
    )
    assert result.exit_code == 1
    assert "kybercore tokens create" in result.output
    assert not (tmp_path / "p.json").exists()


def test_tokens_cli_prints_the_token_once(tmp_path: Path) -> None:
    printers = tmp_path / "printers.json"
    runner = CliRunner()
    created = runner.invoke(
        app, ["tokens", "create", "ops", "--role", "operator", "--printers-file", str(printers)]
    )
    assert created.exit_code == 0, created.output
    token = created.output.strip().splitlines()[-1]
    listed = runner.invoke(app, ["tokens", "list", "--printers-file", str(printers)])
    assert "ops" in listed.output
    assert token not in listed.output
    assert TokenStore(tokens_path_for(printers)).identify(token) is not None


@pytest.fixture(scope="module")
def guarded(
    start_stack: Callable[..., PrinterStack], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[KyberCoreServer, dict[str, str]]]:
    """A server that requires tokens, logging at DEBUG, with a printer that has an API key."""
    folder = tmp_path_factory.mktemp("guarded")
    stack = start_stack("guarded")
    printer = PrinterConfig(
        id="guarded", name="Guarded", moonraker_url=stack.url, api_key=MOONRAKER_KEY
    )
    write_printers(folder / "printers.json", [printer])
    store = TokenStore(tokens_path_for(folder / "printers.json"))
    tokens = {role: store.create(role, role)[1] for role in ("viewer", "operator", "admin")}
    server = KyberCoreServer(folder / "printers.json", free_port(), "--log-level", "debug")
    server.start()
    yield server, tokens
    server.stop()
    stack.stop()


def _as(token: str | None) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"} if token else {}


def test_roles_decide_what_each_token_may_do(
    guarded: tuple[KyberCoreServer, dict[str, str]],
) -> None:
    server, tokens = guarded
    url = server.url
    assert httpx.get(f"{url}/api/session").json() == {
        "access": "tokens",
        "name": None,
        "role": None,
    }
    # A load balancer's check carries no token: readiness is all it is told.
    assert httpx.get(f"{url}/api/ready").json() == {"ready": True}
    anonymous = httpx.get(f"{url}/api/printers")
    assert anonymous.status_code == 401
    assert "kybercore tokens create" in anonymous.json()["error"]["message"]
    assert httpx.get(f"{url}/api/printers", headers=_as(tokens["viewer"])).status_code == 200
    viewer_acts = httpx.post(
        f"{url}/api/printers/guarded/actions/home", headers=_as(tokens["viewer"])
    )
    assert viewer_acts.status_code == 403
    assert "operator role" in viewer_acts.json()["error"]["message"]
    operator_acts = httpx.post(
        f"{url}/api/printers/nope/actions/home", headers=_as(tokens["operator"])
    )
    assert operator_acts.status_code == 404  # past the door, refused by the fleet
    new = {"name": "X", "moonraker_url": "http://127.0.0.1:1"}
    assert (
        httpx.post(f"{url}/api/printers", json=new, headers=_as(tokens["operator"])).status_code
        == 403
    )
    added = httpx.post(f"{url}/api/printers", json=new, headers=_as(tokens["admin"]))
    assert added.status_code == 201
    assert httpx.delete(f"{url}/api/printers/x", headers=_as(tokens["admin"])).status_code == 204
    assert httpx.get(f"{url}/api/printers", headers=_as("kc_forged")).status_code == 401


async def test_the_browser_logs_in_with_a_cookie_for_rest_and_websocket(
    guarded: tuple[KyberCoreServer, dict[str, str]],
) -> None:
    server, tokens = guarded
    with pytest.raises(websockets.InvalidStatus):
        async with websockets.connect(server.ws_url):
            pass
    async with httpx.AsyncClient(base_url=server.url) as browser:
        wrong = await browser.post("/api/session", json={"token": "kc_wrong"})
        assert wrong.status_code == 401
        login = await browser.post("/api/session", json={"token": tokens["viewer"]})
        assert login.status_code == 200
        assert login.json()["role"] == "viewer"
        cookie = login.headers["set-cookie"]
        assert "HttpOnly" in cookie
        assert "SameSite=strict" in cookie or "SameSite=Strict" in cookie
        assert (await browser.get("/api/printers")).status_code == 200
        headers = {"Cookie": f"{COOKIE}={browser.cookies[COOKIE]}"}
        async with websockets.connect(server.ws_url, additional_headers=headers) as ws:
            first = json.loads(await ws.recv())
            assert first["type"] == "snapshot"
        evil = {**headers, "Origin": "http://evil.example"}
        with pytest.raises(websockets.InvalidStatus):
            async with websockets.connect(server.ws_url, additional_headers=evil):
                pass
        assert (await browser.delete("/api/session")).status_code == 204
        assert (await browser.get("/api/printers")).status_code == 401


def test_cross_origin_writes_are_refused_and_pages_carry_security_headers(
    guarded: tuple[KyberCoreServer, dict[str, str]],
) -> None:
    server, tokens = guarded
    forged = httpx.post(
        f"{server.url}/api/printers/guarded/actions/emergency_stop",
        headers={**_as(tokens["admin"]), "Origin": "http://evil.example"},
    )
    assert forged.status_code == 403
    assert forged.json()["error"]["code"] == "cross_origin"
    page = httpx.get(f"{server.url}/api/session")
    assert "frame-ancestors 'none'" in page.headers["content-security-policy"]
    assert page.headers["x-content-type-options"] == "nosniff"
    assert "access-control-allow-origin" not in page.headers


def test_no_secret_in_any_answer_frame_or_log_line(
    guarded: tuple[KyberCoreServer, dict[str, str]],
) -> None:
    server, tokens = guarded
    admin = _as(tokens["admin"])
    seen = [
        httpx.get(f"{server.url}/api/printers", headers=admin).text,
        httpx.get(f"{server.url}/api/printers/guarded", headers=admin).text,
        httpx.patch(
            f"{server.url}/api/printers/guarded", json={"api_key": MOONRAKER_KEY}, headers=admin
        ).text,
        httpx.get(f"{server.url}/openapi.json").text,
    ]
    assert httpx.get(f"{server.url}/api/printers/guarded", headers=admin).json()["api_key_set"]
    log = server.log.read_text()
    assert "DEBUG" in log  # the strictest logging there is
    for secret in (MOONRAKER_KEY, *tokens.values()):
        for text in (*seen, log):
            assert secret not in text
