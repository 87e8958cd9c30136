"""Notifications over HTTP: ``/api/notifications/...`` — channels, their deliveries, the
fleet-wide noise settings and the event kinds (:mod:`kybercore.notify`).

Who may do what: viewers read the settings and the kinds; operators list channels, add
them, send tests and read the deliveries; a channel is changed or removed by the role its
rules name (``min_role``, admin unless the channel says operator), and only an admin adds
a channel only admins may change. The noise settings are an admin's.

Secrets are write-only, like API keys: a webhook's signing key is returned once, in the
answer that created it (generated when none was given), and never again; a channel's
target is shown masked (an Apprise URL carries its service's token).
"""

from __future__ import annotations

import asyncio
import secrets
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from starlette.requests import HTTPConnection

from kybercore.api.auth import Identity, Role
from kybercore.api.deps import ADMIN, OPERATOR, VIEWER, Operator, started
from kybercore.api.models import ERROR_RESPONSES
from kybercore.api.notify_models import (
    KIND_LABELS,
    ChannelCreate,
    ChannelCreated,
    ChannelOut,
    ChannelPatch,
    DeliveryOut,
    KindOut,
    SettingsBody,
    webhook_url_problem,
)
from kybercore.api.recorder import note
from kybercore.errors import AccessDenied
from kybercore.notify.models import DEFAULT_EVENTS, EVENT_KINDS, SEVERITY
from kybercore.notify.records import ChannelKind, mask_target
from kybercore.notify.senders import check_apprise_url
from kybercore.notify.service import NotifyService

router = APIRouter()

MAX_ID = 2**31 - 1
TEST_WAIT = 10.0
"""Seconds a test waits for the channel's answer before it answers "still pending"."""
SECRET_BYTES = 32


async def notify_service(connection: HTTPConnection) -> NotifyService:
    """The app's NotifyService, started by the lifespan."""
    service: NotifyService = started(connection, "notify", "Notifications")
    return service


Notify = Annotated[NotifyService, Depends(notify_service)]
Admin = Annotated[Identity, ADMIN]
ChannelId = Annotated[int, Path(ge=1, le=MAX_ID, description="The channel's id.")]


@router.get(
    "/api/notifications/channels",
    response_model=list[ChannelOut],
    responses=ERROR_RESPONSES,
    dependencies=[OPERATOR],
)
async def list_channels(notify: Notify) -> list[dict[str, Any]]:
    """Every channel, targets masked, secrets never shown."""
    return [channel.public() for channel in await notify.store.channels()]


@router.post(
    "/api/notifications/channels",
    status_code=201,
    response_model=ChannelCreated,
    responses=ERROR_RESPONSES,
)
async def add_channel(
    request: Request, notify: Notify, user: Operator, body: ChannelCreate
) -> dict[str, Any]:
    """Add a channel. A webhook gets a signing key (``secret``; generated unless given),
    shown in this answer only: keep it where the receiver checks signatures."""
    _may_change(user, body.rules.min_role, "add a channel only admins may change")
    await _check_target(body.kind, body.target)
    secret = body.secret
    if body.kind == "apprise" and secret is not None:
        raise _field_error("secret", "an Apprise channel has no secret: its URL carries "
                           "the service's credentials; leave secret out")  # fmt: skip
    if body.kind == "webhook" and secret is None:
        secret = secrets.token_urlsafe(SECRET_BYTES)
    note(request, params={"target": mask_target(body.kind, body.target)})
    channel = await notify.store.add_channel(
        name=body.name,
        kind=body.kind,
        target=body.target,
        secret=secret,
        rules=body.rules.rules(),
        enabled=body.enabled,
        user=user.name,
    )
    return {**channel.public(), "secret": secret}


@router.patch(
    "/api/notifications/channels/{channel_id}",
    response_model=ChannelOut,
    responses=ERROR_RESPONSES,
)
async def edit_channel(
    request: Request, notify: Notify, user: Operator, channel_id: ChannelId, patch: ChannelPatch
) -> dict[str, Any]:
    """Change a channel (omitted fields stay); needs the role the channel's rules name."""
    channel = await notify.store.channel(channel_id)
    _may_change(user, channel.rules.min_role, f"change channel {channel_id}")
    changes: dict[str, Any] = {
        name: getattr(patch, name)
        for name in patch.model_fields_set
        if getattr(patch, name) is not None
    }
    if patch.rules is not None:
        _may_change(user, patch.rules.min_role, "let only admins change a channel")
        changes["rules"] = patch.rules.rules()
    if patch.target is not None:
        await _check_target(channel.kind, patch.target)
        note(request, params={"target": mask_target(channel.kind, patch.target)})
    if patch.secret is not None and channel.kind == "apprise":
        raise _field_error("secret", "an Apprise channel has no secret: its URL carries "
                           "the service's credentials")  # fmt: skip
    updated = await notify.store.update_channel(channel_id, user=user.name, **changes)
    return updated.public()


@router.delete(
    "/api/notifications/channels/{channel_id}", status_code=204, responses=ERROR_RESPONSES
)
async def remove_channel(notify: Notify, user: Operator, channel_id: ChannelId) -> Response:
    """Remove a channel and its deliveries (sent or not); needs the channel's role."""
    channel = await notify.store.channel(channel_id)
    _may_change(user, channel.rules.min_role, f"remove channel {channel_id}")
    await notify.store.remove_channel(channel_id)
    return Response(status_code=204)


@router.post(
    "/api/notifications/channels/{channel_id}/test",
    response_model=DeliveryOut,
    responses=ERROR_RESPONSES,
)
async def test_channel(notify: Notify, user: Operator, channel_id: ChannelId) -> dict[str, Any]:
    """Send a test message now (whatever the channel's rules, enabled or not) and answer
    how it went: ``delivered``, or ``pending`` with the receiver's error and the time of
    the next try. Waits up to 10 s for the receiver."""
    delivery = await notify.send_test(channel_id, user.name, wait=TEST_WAIT)
    return delivery.to_json()


@router.get(
    "/api/notifications/deliveries",
    response_model=list[DeliveryOut],
    responses=ERROR_RESPONSES,
    dependencies=[OPERATOR],
)
async def deliveries(
    notify: Notify,
    channel_id: Annotated[
        int | None, Query(ge=1, le=MAX_ID, description="Only this channel's.")
    ] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> list[dict[str, Any]]:
    """The delivery log, newest first."""
    if channel_id is not None:
        await notify.store.channel(channel_id)  # an unknown channel is a 404, not []
    return [d.to_json() for d in await notify.store.deliveries(channel_id, limit)]


@router.get(
    "/api/notifications/settings",
    response_model=SettingsBody,
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def get_settings(notify: Notify) -> SettingsBody:
    """The fleet-wide noise control: cooldown, folding, storms, grace and waits."""
    # From the database: on NATS, the service running may be another front's.
    return SettingsBody.of(await notify.store.settings())


@router.put("/api/notifications/settings", response_model=SettingsBody, responses=ERROR_RESPONSES)
async def put_settings(notify: Notify, _user: Admin, body: SettingsBody) -> SettingsBody:
    """Replace the noise settings; they apply at once."""
    await notify.apply_settings(body.settings())
    return SettingsBody.of(notify.settings)


@router.get(
    "/api/notifications/kinds",
    response_model=list[KindOut],
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def kinds() -> list[KindOut]:
    """Every event kind, in the order a page lists them, with its labels and severity."""
    return [
        KindOut(
            kind=kind,
            severity=SEVERITY[kind],
            default=kind in DEFAULT_EVENTS,
            en=KIND_LABELS[kind][0],
            es=KIND_LABELS[kind][1],
        )
        for kind in EVENT_KINDS
    ]


# -- helpers ------------------------------------------------------------------------------


def _may_change(user: Identity, role: Role, what: str) -> None:
    if not user.may(role):
        raise AccessDenied(
            f"Your token ({user.name}, {user.role}) may not {what}: it needs the {role} "
            "role. Ask an admin, or for a token with that role.",
            code="forbidden",
        )


async def _check_target(kind: ChannelKind, target: str) -> None:
    """A 422 naming ``target`` when it is no address for a ``kind`` channel."""
    if kind == "webhook":
        problem = webhook_url_problem(target)
    else:  # Apprise loads its plugins on first use: off the event loop
        problem = await asyncio.to_thread(_apprise_problem, target)
    if problem is not None:
        raise _field_error("target", problem)


def _apprise_problem(target: str) -> str | None:
    try:
        return check_apprise_url(target)
    except Exception:  # a third-party parser: whatever it chokes on is not a usable URL
        return "Apprise cannot read this URL; check it against its service's documentation"


def _field_error(field: str, message: str) -> RequestValidationError:
    return RequestValidationError([{"type": "value_error", "loc": ("body", field), "msg": message}])
