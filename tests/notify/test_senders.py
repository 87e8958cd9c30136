"""Sending for real to a loopback receiver: signed webhooks (checked with ``verify`` and
with the README's stdlib-only snippet), failures as results, and real Apprise ``json://``
and ``form://`` targets — no mock of Apprise."""

from __future__ import annotations

import base64
import hashlib
import hmac
import re

import httpx
import orjson

from kybercore.notify.models import FleetEvent
from kybercore.notify.senders import (
    DELIVERY_HEADER,
    EVENT_HEADER,
    SIGNATURE_HEADER,
    TIMESTAMP_HEADER,
    check_apprise_url,
    send_apprise,
    send_webhook,
    sign,
    verify,
    webhook_body,
)
from kybercore.notify.texts import render
from kybercore.sim.stack import free_port
from tests.notify.conftest import SECRET, fleet_event
from tests.notify.receiver import Receiver

JPEG = b"\xff\xd8\xff\xe0" + b"\x00\x10JFIF" + bytes(range(256)) * 4 + b"\xff\xd9"


def readme_verify(secret: str, headers: dict[str, str], body: bytes) -> bool:
    """The check a receiver writes from the README, with the standard library only."""
    timestamp = headers["x-kybercore-timestamp"]
    expected = hmac.new(
        secret.encode(), timestamp.encode() + b"." + body, hashlib.sha256
    ).hexdigest()
    return hmac.compare_digest("sha256=" + expected, headers["x-kybercore-signature"])


async def test_a_signed_webhook_verifies_and_a_tampered_one_does_not(
    http: httpx.AsyncClient, receiver: Receiver
) -> None:
    event = fleet_event("print_failed", "a")
    title, body = render(event, "en")
    result = await send_webhook(http, receiver.url(), SECRET, event, title, body, None)
    assert (result.ok, result.code, result.error) == (True, 200, "")
    (got,) = receiver.requests
    headers = got.headers
    assert headers[EVENT_HEADER.lower()] == "print_failed"
    assert headers[DELIVERY_HEADER.lower()] == event.id
    assert headers["content-type"] == "application/json"
    timestamp, signature = headers[TIMESTAMP_HEADER.lower()], headers[SIGNATURE_HEADER.lower()]
    assert re.fullmatch(r"sha256=[0-9a-f]{64}", signature)
    assert verify(SECRET, timestamp, got.body, signature)
    assert readme_verify(SECRET, headers, got.body)
    assert signature == sign(SECRET, int(timestamp), got.body)
    tampered = got.body.replace(b"print_failed", b"print_complete")
    assert not verify(SECRET, timestamp, tampered, signature)
    assert not readme_verify(SECRET, headers, tampered)
    assert not verify("another secret", timestamp, got.body, signature)
    assert not verify(SECRET, str(int(timestamp) + 1), got.body, signature)
    # The body is the event's JSON with its words: a receiver reads it back whole.
    payload = got.json()
    assert (payload["title"], payload["message"]) == (title, body)
    assert FleetEvent.from_json(payload).to_json() == event.to_json()
    assert "snapshot" not in payload


async def test_without_a_secret_there_is_no_signature_and_a_snapshot_rides_in_base64(
    http: httpx.AsyncClient, receiver: Receiver
) -> None:
    event = fleet_event("print_completed", "voron-2", filename="cube.gcode")
    result = await send_webhook(http, receiver.url(), None, event, "t", "b", JPEG)
    assert result.ok
    (got,) = receiver.requests
    assert SIGNATURE_HEADER.lower() not in got.headers
    assert got.body == webhook_body(event, "t", "b", JPEG)
    snapshot = got.json()["snapshot"]
    assert snapshot["filename"] == "voron-2.jpg"
    assert snapshot["content_type"] == "image/jpeg"
    assert base64.b64decode(snapshot["base64"]) == JPEG


async def test_refusals_and_unreachable_receivers_are_results_not_errors(
    http: httpx.AsyncClient, receiver: Receiver
) -> None:
    event = fleet_event()
    receiver.fail_next(1, 503)
    refused = await send_webhook(http, receiver.url(), SECRET, event, "t", "b", None)
    assert (refused.ok, refused.code) == (False, 503)
    assert refused.error == "The receiver answered HTTP 503: receiver says no"
    down = await send_webhook(
        http, f"http://127.0.0.1:{free_port()}/hook", SECRET, event, "t", "b", None
    )
    assert (down.ok, down.code) == (False, None)
    assert down.error.startswith("Could not reach the receiver: ConnectError")


async def test_apprise_json_delivers_title_body_type_and_snapshot(receiver: Receiver) -> None:
    event = fleet_event("print_failed", "a")
    title, body = render(event, "es")
    target = f"json://127.0.0.1:{receiver.port}/apprise"
    result = await send_apprise(target, title, body, JPEG, severity=event.severity)
    assert result.ok, result.error
    (got,) = receiver.requests
    assert got.path == "/apprise"
    payload = got.json()
    assert (payload["title"], payload["message"], payload["type"]) == (title, body, "failure")
    (attachment,) = payload["attachments"]
    assert attachment["filename"].endswith(".jpg")
    assert attachment["mimetype"] == "image/jpeg"
    assert base64.b64decode(attachment["base64"]) == JPEG


async def test_apprise_form_delivers_the_fields_and_the_file(receiver: Receiver) -> None:
    target = f"form://127.0.0.1:{receiver.port}/form"
    result = await send_apprise(target, "Printer a finished", "cube.gcode is done", JPEG)
    assert result.ok, result.error
    (got,) = receiver.requests
    assert got.headers["content-type"].startswith("multipart/form-data")
    assert b"Printer a finished" in got.body
    assert b"cube.gcode is done" in got.body
    assert JPEG in got.body
    assert b'.jpg"' in got.body
    plain = await send_apprise(target, "no picture", "body", None)
    assert plain.ok
    assert b"filename=" not in receiver.requests[-1].body


async def test_apprise_failures_say_why(receiver: Receiver) -> None:
    receiver.fail_next(1, 500)
    refused = await send_apprise(f"json://127.0.0.1:{receiver.port}/x", "t", "b", None)
    assert not refused.ok
    assert refused.error.startswith("Apprise could not deliver:")
    assert "500" in refused.error
    nonsense = await send_apprise("nope://whatever", "t", "b", None)
    assert not nonsense.ok
    assert "Apprise does not understand this URL" in nonsense.error
    assert check_apprise_url("nope://whatever") == nonsense.error
    assert check_apprise_url(f"json://127.0.0.1:{receiver.port}/x") is None
    assert len(receiver.requests) == 1


def test_the_signature_is_hmac_sha256_over_timestamp_dot_body() -> None:
    body = orjson.dumps({"type": "test"})
    expected = hmac.new(b"k", b"1767225600." + body, hashlib.sha256).hexdigest()
    assert sign("k", 1767225600, body) == f"sha256={expected}"
    assert verify("k", "1767225600", body, f"sha256={expected}")
    assert not verify("k", "1767225600", body, expected)  # the prefix is part of it
    assert not verify("k", "1767225600", body, "")
