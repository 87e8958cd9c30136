"""Sending one notification: a signed webhook (httpx) or an Apprise URL.

A sender never raises for a failed delivery: it answers a :class:`SendResult` that says
what went wrong, and the outbox decides whether to try again.

A webhook is a JSON ``POST`` (the event's JSON, its title and message, and the webcam
snapshot in base64 when there is one) with these headers::

    X-KyberCore-Event: print_failed
    X-KyberCore-Event-Id: 9f0c…            (the same on every retry: dedupe on it)
    X-KyberCore-Timestamp: 1767225600      (unix seconds)
    X-KyberCore-Signature: sha256=<hex>    (only when the channel has a secret)

The signature is HMAC-SHA256 with the channel's secret over ``f"{timestamp}."`` followed by
the body's exact bytes; :func:`verify` checks one as a receiver would.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import hmac
import logging
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import apprise
import httpx
import orjson

from kybercore import __version__
from kybercore.notify.models import FleetEvent, Severity

log = logging.getLogger(__name__)

SIGNATURE_HEADER: Final = "X-KyberCore-Signature"
TIMESTAMP_HEADER: Final = "X-KyberCore-Timestamp"
EVENT_HEADER: Final = "X-KyberCore-Event"
DELIVERY_HEADER: Final = "X-KyberCore-Event-Id"
WEBHOOK_TIMEOUT: Final = httpx.Timeout(15.0, connect=5.0)
APPRISE_TIMEOUT: Final = 30.0
"""Seconds one Apprise notification may take, whatever the service (e-mail is slow)."""
_ERROR_TEXT: Final = 300
# Apprise's message type sets the colour or icon on most services.
_APPRISE_TYPES: Final[dict[Severity, apprise.NotifyType]] = {
    "info": apprise.NotifyType.INFO,
    "warning": apprise.NotifyType.WARNING,
    "critical": apprise.NotifyType.FAILURE,
}


@dataclass(frozen=True, slots=True)
class SendResult:
    """How one attempt went: ``ok``, the receiver's HTTP status when known, and why not."""

    ok: bool
    code: int | None = None
    error: str = ""


def sign(secret: str, timestamp: int, body: bytes) -> str:
    """The signature header's value: ``sha256=`` + hex HMAC-SHA256 of ``"{timestamp}." + body``."""
    mac = hmac.new(secret.encode(), f"{timestamp}.".encode() + body, hashlib.sha256)
    return "sha256=" + mac.hexdigest()


def verify(secret: str, timestamp: str, body: bytes, signature: str) -> bool:
    """Whether ``signature`` (the header's value) signs ``body`` sent at ``timestamp`` (the
    timestamp header's value, as received) with ``secret``; compared in constant time."""
    mac = hmac.new(secret.encode(), timestamp.encode() + b"." + body, hashlib.sha256)
    return hmac.compare_digest("sha256=" + mac.hexdigest(), signature.strip())


def webhook_body(event: FleetEvent, title: str, body: str, snapshot: bytes | None) -> bytes:
    """The JSON a webhook receives: the event, its rendered title and message, and the
    snapshot (``filename``, ``content_type``, ``base64``) when there is one."""
    payload = {**event.to_json(), "title": title, "message": body}
    if snapshot is not None:
        payload["snapshot"] = {
            "filename": f"{event.printer.id if event.printer else 'fleet'}.jpg",
            "content_type": "image/jpeg",
            "base64": base64.b64encode(snapshot).decode("ascii"),
        }
    return orjson.dumps(payload)


async def send_webhook(
    http: httpx.AsyncClient,
    url: str,
    secret: str | None,
    event: FleetEvent,
    title: str,
    body: str,
    snapshot: bytes | None,
) -> SendResult:
    """POST the event to ``url``, signed when there is a ``secret``. Any 2xx is a delivery;
    redirects are not followed (a receiver that moved is a failure to fix, not to chase)."""
    content = webhook_body(event, title, body, snapshot)
    timestamp = int(time.time())
    headers = {
        "Content-Type": "application/json",
        "User-Agent": f"KyberCore/{__version__}",
        EVENT_HEADER: event.kind,
        DELIVERY_HEADER: event.id,
        TIMESTAMP_HEADER: str(timestamp),
    }
    if secret:
        headers[SIGNATURE_HEADER] = sign(secret, timestamp, content)
    try:
        answer = await http.post(
            url, content=content, headers=headers, timeout=WEBHOOK_TIMEOUT, follow_redirects=False
        )
    except httpx.TimeoutException:
        return SendResult(False, None, f"The receiver did not answer within {_seconds()} s.")
    except httpx.HTTPError as exc:
        return SendResult(False, None, _cut(f"Could not reach the receiver: {_describe(exc)}"))
    if answer.is_success:
        return SendResult(True, answer.status_code)
    detail = answer.text.strip()
    return SendResult(
        False,
        answer.status_code,
        _cut(
            f"The receiver answered HTTP {answer.status_code}" + (f": {detail}" if detail else "")
        ),
    )


async def send_apprise(
    url: str, title: str, body: str, snapshot: bytes | None, *, severity: Severity = "info"
) -> SendResult:
    """Notify one Apprise URL (ntfy, Telegram, Discord, Slack, e-mail…); the snapshot is
    attached as a ``.jpg``. Apprise is blocking: it runs in a worker thread."""
    return await asyncio.to_thread(_notify, url, title, body, snapshot, severity)


def check_apprise_url(url: str) -> str | None:
    """Why Apprise cannot use ``url`` (a message), or None when it can."""
    if _apprise().add(url):
        return None
    return (
        "Apprise does not understand this URL. Write it as its service's documentation "
        "says, e.g. ntfys://ntfy.sh/topic or tgram://bot-token/chat-id."
    )


def _notify(
    url: str, title: str, body: str, snapshot: bytes | None, severity: Severity
) -> SendResult:
    sender = _apprise()
    if not sender.add(url):
        return SendResult(False, None, check_apprise_url(url) or "")
    kind = _APPRISE_TYPES[severity]
    with tempfile.TemporaryDirectory(prefix="kybercore-notify-") as folder:
        attach = None
        if snapshot is not None:
            path = Path(folder) / "snapshot.jpg"
            path.write_bytes(snapshot)
            attach = apprise.AppriseAttachment(str(path))
        result = sender.notify(
            body=body, title=title, notify_type=kind, attach=attach, timeout=APPRISE_TIMEOUT
        )
    if result:
        return SendResult(True)
    said = "; ".join(dict.fromkeys(entry.message for entry in result.logs()))
    return SendResult(False, None, _cut(f"Apprise could not deliver: {said or 'no reason given'}"))


def _apprise() -> apprise.Apprise:
    # Memory storage: Apprise must not write caches under the service user's home.
    return apprise.Apprise(asset=apprise.AppriseAsset(storage_mode="memory"))


def _describe(exc: httpx.HTTPError) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _seconds() -> str:
    return f"{WEBHOOK_TIMEOUT.read:g}"


def _cut(text: str) -> str:
    return text if len(text) <= _ERROR_TEXT else text[:_ERROR_TEXT] + "…"
