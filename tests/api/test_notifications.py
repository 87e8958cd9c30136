"""``/api/notifications/...`` in the app itself (its lifespan, its database, tokens with
roles), with a real loopback webhook receiver: channels by role, secrets shown once, clear
refusals, a test's outcome, the delivery log, the settings and the audit trail."""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import FastAPI

from kybercore.api.app import create_app
from kybercore.api.auth import TokenStore, tokens_path_for
from kybercore.api.security import Access
from kybercore.notify.models import EVENT_KINDS
from kybercore.notify.senders import verify
from kybercore.registry.store import PrinterRegistry, write_printers
from tests.notify.receiver import Receiver

RETRY = {"first_retry": 0.2, "max_retry": 1.0}
APPRISE_URL = "json://127.0.0.1:9/apprise-token-that-is-a-secret"


@dataclass
class Api:
    """The app, and a client for it that acts as one of three tokens."""

    app: FastAPI
    client: httpx.AsyncClient
    tokens: dict[str, str]

    async def call(self, role: str, method: str, path: str, **request: Any) -> httpx.Response:
        headers = {"Authorization": f"Bearer {self.tokens[role]}"}
        return await self.client.request(method, path, headers=headers, **request)


@pytest.fixture
async def api(tmp_path: Path) -> AsyncIterator[Api]:
    """An app with no printers, in tokens mode: an admin, an operator and a viewer."""
    path = tmp_path / "printers.json"
    write_printers(path, [])
    store = TokenStore(tokens_path_for(path))
    tokens = {role: store.create(f"{role}-1", role)[1] for role in ("admin", "operator", "viewer")}
    options = {"tick": 0.05, "queue_poll": 0.1, "outbox_options": RETRY}
    app = create_app(PrinterRegistry(path), Access(store), notify_options=options)
    async with (
        app.router.lifespan_context(app),
        httpx.AsyncClient(
            transport=httpx.ASGITransport(app), base_url="http://127.0.0.1", timeout=30
        ) as client,
    ):
        yield Api(app, client, tokens)


def webhook(receiver: Receiver, **fields: Any) -> dict[str, Any]:
    return {"name": "ops hook", "kind": "webhook", "target": receiver.url(), **fields}


async def test_a_webhook_secret_is_shown_once_and_signs_what_is_sent(
    api: Api, receiver: Receiver
) -> None:
    created = await api.call("admin", "POST", "/api/notifications/channels", json=webhook(receiver))
    assert created.status_code == 201, created.text
    channel = created.json()
    secret = channel["secret"]
    assert len(secret) >= 32
    assert channel["has_secret"] is True
    assert channel["rules"]["min_role"] == "admin"
    listed = await api.call("operator", "GET", "/api/notifications/channels")
    assert listed.status_code == 200
    assert secret not in listed.text
    assert [c["id"] for c in listed.json()] == [channel["id"]]
    assert "secret" not in listed.json()[0]

    tested = await api.call("operator", "POST", f"/api/notifications/channels/{channel['id']}/test")
    assert tested.status_code == 200, tested.text
    assert (tested.json()["status"], tested.json()["response_code"]) == ("delivered", 200)
    [request] = receiver.accepted
    headers = request.headers
    assert verify(
        secret, headers["x-kybercore-timestamp"], request.body, headers["x-kybercore-signature"]
    )
    log = await api.call("operator", "GET", "/api/notifications/deliveries",
                         params={"channel_id": channel["id"]})  # fmt: skip
    assert [(d["kind"], d["status"]) for d in log.json()] == [("test", "delivered")]
    # The audit log has the action, never the secret.
    audit = (await api.call("admin", "GET", "/api/audit")).text
    assert "channel.add" in audit
    assert "channel.test" in audit
    assert secret not in audit


async def test_a_given_secret_is_kept_and_an_apprise_target_is_masked_everywhere(
    api: Api, receiver: Receiver
) -> None:
    given = "my-own-secret-of-some-length"
    created = await api.call(
        "admin", "POST", "/api/notifications/channels", json=webhook(receiver, secret=given)
    )
    assert created.json()["secret"] == given
    apprise = {"name": "phones", "kind": "apprise", "target": APPRISE_URL}
    created = await api.call("admin", "POST", "/api/notifications/channels", json=apprise)
    assert created.status_code == 201, created.text
    assert (created.json()["secret"], created.json()["has_secret"]) == (None, False)
    token = "apprise-token-that-is-a-secret"
    assert token not in created.text
    assert token not in (await api.call("admin", "GET", "/api/notifications/channels")).text
    assert token not in (await api.call("admin", "GET", "/api/audit")).text


async def test_roles_decide_who_reads_adds_changes_and_removes(
    api: Api, receiver: Receiver
) -> None:
    channels = "/api/notifications/channels"
    assert (await api.call("viewer", "GET", channels)).status_code == 403
    assert (await api.call("viewer", "POST", channels, json=webhook(receiver))).status_code == 403
    # An operator may not add a channel only admins could change...
    refused = await api.call("operator", "POST", channels, json=webhook(receiver))
    assert refused.status_code == 403
    assert "admin" in refused.json()["error"]["message"]
    # ...but one operators may change, and change and remove it.
    mine = webhook(receiver, rules={"min_role": "operator"})
    created = await api.call("operator", "POST", channels, json=mine)
    assert created.status_code == 201, created.text
    ops_id = created.json()["id"]
    edited = await api.call("operator", "PATCH", f"{channels}/{ops_id}", json={"enabled": False})
    assert (edited.status_code, edited.json()["enabled"]) == (200, False)
    # Raising it to admins only is an admin's to do.
    raised = {"rules": {"min_role": "admin"}}
    assert (
        await api.call("operator", "PATCH", f"{channels}/{ops_id}", json=raised)
    ).status_code == 403
    admins = (await api.call("admin", "POST", channels, json=webhook(receiver))).json()["id"]
    for method in ("PATCH", "DELETE"):
        body = {"json": {"name": "x"}} if method == "PATCH" else {}
        answer = await api.call("operator", method, f"{channels}/{admins}", **body)
        assert answer.status_code == 403, (method, answer.text)
    assert (await api.call("operator", "DELETE", f"{channels}/{ops_id}")).status_code == 204
    assert (await api.call("admin", "DELETE", f"{channels}/{admins}")).status_code == 204
    assert (await api.call("admin", "GET", channels)).json() == []
    # Settings: anyone reads, admins change.
    settings = (await api.call("viewer", "GET", "/api/notifications/settings")).json()
    put = "/api/notifications/settings"
    assert (await api.call("operator", "PUT", put, json=settings)).status_code == 403
    assert (await api.call("admin", "PUT", put, json=settings)).status_code == 200


async def test_edits_apply_and_unknown_channels_are_404(api: Api, receiver: Receiver) -> None:
    channels = "/api/notifications/channels"
    created = (await api.call("admin", "POST", channels, json=webhook(receiver))).json()
    patch = {
        "name": "night",
        "rules": {"events": ["print_failed"], "locations": ["Room B"], "language": "es",
                  "quiet_hours": {"start": "22:00", "end": "07:00", "allow_critical": False}},
    }  # fmt: skip
    edited = await api.call("admin", "PATCH", f"{channels}/{created['id']}", json=patch)
    assert edited.status_code == 200, edited.text
    rules = edited.json()["rules"]
    assert (edited.json()["name"], rules["events"], rules["language"]) == (
        "night", ["print_failed"], "es",
    )  # fmt: skip
    assert rules["quiet_hours"] == {"start": "22:00", "end": "07:00", "allow_critical": False}
    # A new secret is taken, never shown, and signs from now on.
    rotated = "a-brand-new-secret-0123456789"
    path = f"{channels}/{created['id']}"
    answer = await api.call("admin", "PATCH", path, json={"secret": rotated})
    assert (answer.status_code, answer.json()["has_secret"]) == (200, True)
    assert rotated not in answer.text
    assert (await api.call("admin", "POST", f"{path}/test")).json()["status"] == "delivered"
    request = receiver.accepted[-1]
    timestamp, signature = (
        request.headers[h] for h in ("x-kybercore-timestamp", "x-kybercore-signature")
    )
    assert verify(rotated, timestamp, request.body, signature)
    for method, path in (
        ("PATCH", f"{channels}/999"),
        ("DELETE", f"{channels}/999"),
        ("POST", f"{channels}/999/test"),
        ("GET", "/api/notifications/deliveries?channel_id=999"),
    ):
        body = {"json": {"name": "x"}} if method == "PATCH" else {}
        answer = await api.call("admin", method, path, **body)
        assert answer.status_code == 404, (method, path, answer.text)
        assert answer.json()["error"]["code"] == "channel_not_found"


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        ({"target": "ftp://hooks.example/x"}, "target", "http:// or https://"),
        ({"target": "not a url"}, "target", "http:// or https://"),
        ({"kind": "pager"}, "kind", "webhook"),
        ({"kind": "apprise", "target": "nonsense://what"}, "target", "Apprise"),
        ({"kind": "apprise", "target": APPRISE_URL, "secret": "x" * 20}, "secret", "Apprise"),
        ({"secret": "short"}, "secret", "16"),
        ({"rules": {"quiet_hours": {"start": "25:00", "end": "07:00"}}}, "rules.quiet_hours.start",
         "HH:MM"),
        ({"rules": {"quiet_hours": {"start": "22:00", "end": "7pm"}}}, "rules.quiet_hours.end",
         "HH:MM"),
        ({"rules": {"events": ["print_exploded"]}}, "rules.events.0", "print_started"),
        ({"rules": {"min_role": "viewer"}}, "rules.min_role", "operator"),
        ({"name": ""}, "name", "at least 1"),
    ],
)  # fmt: skip
async def test_a_bad_channel_is_refused_naming_the_field_and_the_fix(
    api: Api, receiver: Receiver, body: dict[str, Any], field: str, words: str
) -> None:
    answer = await api.call(
        "admin", "POST", "/api/notifications/channels", json={**webhook(receiver), **body}
    )
    assert answer.status_code == 422, answer.text
    error = answer.json()["error"]
    assert [f["field"] for f in error["fields"]] == [field], error
    assert words in error["fields"][0]["en"], error
    assert (await api.call("admin", "GET", "/api/notifications/channels")).json() == []


async def test_a_bad_setting_is_refused_and_a_good_one_applies_at_once(api: Api) -> None:
    put = "/api/notifications/settings"
    settings = (await api.call("viewer", "GET", put)).json()
    assert settings["fold_window_s"] == 20.0
    bad = await api.call("admin", "PUT", put, json={**settings, "storm_threshold": 0})
    assert bad.status_code == 422
    assert bad.json()["error"]["fields"][0]["field"] == "storm_threshold"
    changed = {**settings, "cooldown_s": 60.0, "storm_threshold": 10}
    assert (await api.call("admin", "PUT", put, json=changed)).json() == changed
    assert api.app.state.notify.settings.storm_threshold == 10
    assert (await api.call("viewer", "GET", put)).json() == changed


async def test_the_kinds_are_listed_in_order_with_labels_and_severity(api: Api) -> None:
    kinds = (await api.call("viewer", "GET", "/api/notifications/kinds")).json()
    assert [k["kind"] for k in kinds] == list(EVENT_KINDS)
    by_kind = {k["kind"]: k for k in kinds}
    assert by_kind["printer_offline"]["severity"] == "critical"
    assert by_kind["first_layer_done"]["default"] is False
    assert by_kind["print_failed"]["es"] == "Impresión fallida"


async def test_a_test_to_a_receiver_that_is_down_answers_pending_with_the_error(
    api: Api,
) -> None:
    down = Receiver()  # never started
    body = {"name": "down", "kind": "webhook", "target": down.url()}
    created = (await api.call("admin", "POST", "/api/notifications/channels", json=body)).json()
    tested = await api.call("operator", "POST", f"/api/notifications/channels/{created['id']}/test")
    assert tested.status_code == 200
    delivery = tested.json()
    assert (delivery["status"], delivery["attempts"]) == ("pending", 1)
    assert delivery["last_error"]
    assert delivery["next_at"]
