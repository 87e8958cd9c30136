"""The audit log: who did what to which printer or job, when, from where, and how it ended.

One row per action: the actor (a token's name, ``local`` on an open server, ``cli:<user>``
for the command line), their role, the action (``printer.edit``, ``printer.cancel``,
``plate.clear``, ``token.create``...), its target (``printer:<id>``, ``job:<id>``,
``token:<id>``), its parameters, its outcome (``ok`` or the error's code), the client's
address and the request id.

Append-only: this module inserts and reads, nothing in KyberCore updates or deletes a row,
and the database refuses to (the triggers of migration ``0003_audit``).

No secret is ever stored: :func:`redact` replaces the value of every parameter whose name
says it holds one (API keys, tokens, passwords...), any KyberCore token wherever it appears
in a value, and the password of a URL, before a row is written.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, Final

from sqlalchemy import (
    JSON,
    BigInteger,
    Column,
    Index,
    Integer,
    MetaData,
    String,
    Table,
    func,
    or_,
    select,
)
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine
from sqlalchemy.sql.elements import ColumnElement

from kybercore.aio import cancel_and_wait
from kybercore.db import UTCDateTime, transaction
from kybercore.errors import DatabaseUnavailable

log = logging.getLogger(__name__)

metadata = MetaData()
"""The audit table alone: migration ``0003_audit`` creates it."""

audit = Table(
    "audit",
    metadata,
    Column("id", BigInteger().with_variant(Integer, "sqlite"), primary_key=True),
    Column("at", UTCDateTime, nullable=False),
    Column("actor", String(128), nullable=False),
    Column("role", String(16), nullable=False),
    Column("action", String(64), nullable=False),
    Column("target", String(256), nullable=False),
    Column("params", JSON, nullable=False),
    Column("outcome", String(64), nullable=False),
    Column("client", String(128), nullable=False),
    Column("request_id", String(64), nullable=False),
    Index("ix_audit_at", "at"),
    Index("ix_audit_actor", "actor", "at"),
    Index("ix_audit_target", "target", "at"),
    Index("ix_audit_action", "action", "at"),
)

RETRY_SECONDS: Final = 2.0
"""How often rows the database did not take are tried again."""
REDACTED: Final = "[redacted]"
# A parameter named like one of these holds a secret, whatever its value looks like.
_SECRET_NAME: Final = re.compile(
    r"api[_-]?key|apikey|token|passw|secret|authori[sz]ation|cookie|credential|private",
    re.IGNORECASE,
)
# KyberCore tokens (kc_ + 43 url-safe characters) wherever they turn up in a value, and the
# password in a URL's user info (http://user:password@host).
_TOKEN: Final = re.compile(r"kc_[A-Za-z0-9_-]{16,}")
_URL_PASSWORD: Final = re.compile(r"(//[^/@\s:]*:)[^/@\s]*@")
_BEARER: Final = re.compile(r"(?i)(bearer\s+)\S+")
MAX_TEXT: Final = 2000
"""Longer strings (a G-code script) are cut: the log says what was done, not all of it."""
MAX_ITEMS: Final = 200
MAX_LIMIT: Final = 1000


def redact(value: Any, name: str = "") -> Any:
    """``value`` (parameters: JSON-like data) with every secret replaced by ``[redacted]``.

    Empty and null secrets stay as they are: "the API key was removed" is not a secret.
    """
    if name and _SECRET_NAME.search(name) and value not in (None, "", [], {}):
        return REDACTED
    if isinstance(value, Mapping):
        return {str(k): redact(v, str(k)) for k, v in list(value.items())[:MAX_ITEMS]}
    if isinstance(value, list | tuple):
        return [redact(v) for v in value[:MAX_ITEMS]]
    if isinstance(value, bool | int | float) or value is None:
        return value
    text = str(value)
    text = _BEARER.sub(r"\1" + REDACTED, text)
    text = _URL_PASSWORD.sub(r"\1" + REDACTED + "@", _TOKEN.sub(REDACTED, text))
    return text if len(text) <= MAX_TEXT else text[:MAX_TEXT] + "…"


@dataclass(frozen=True)
class AuditEntry:
    """One action to record."""

    actor: str
    role: str
    action: str
    target: str = ""
    params: Mapping[str, Any] = field(default_factory=dict)
    outcome: str = "ok"
    """``ok``, or the error's code (``unknown_printer``, ``forbidden``...)."""
    client: str = ""
    request_id: str = ""
    at: datetime | None = None
    """When it happened; now when not given."""

    def row(self, now: datetime) -> dict[str, Any]:
        """The row to insert: redacted, every text cut to its column."""
        return {
            "at": self.at or now,
            "actor": self.actor[:128],
            "role": self.role[:16],
            "action": self.action[:64],
            "target": self.target[:256],
            "params": redact(dict(self.params)),
            "outcome": self.outcome[:64],
            "client": self.client[:128],
            "request_id": self.request_id[:64],
        }


@dataclass(frozen=True)
class AuditQuery:
    """Which rows to read: every filter given must hold. ``target`` matches a whole target
    (``printer:a``) or its id (``a``)."""

    actor: str | None = None
    target: str | None = None
    action: str | None = None
    since: datetime | None = None
    until: datetime | None = None
    limit: int = 50
    offset: int = 0

    def where(self) -> list[ColumnElement[bool]]:
        """The SQL conditions of these filters."""
        c = audit.c
        conditions: list[ColumnElement[bool]] = []
        if self.actor:
            conditions.append(c.actor == self.actor)
        if self.action:
            conditions.append(c.action == self.action)
        if self.target:
            conditions.append(
                or_(c.target == self.target, c.target.endswith(":" + self.target, autoescape=True))
            )
        if self.since is not None:
            conditions.append(c.at >= self.since)
        if self.until is not None:
            conditions.append(c.at < self.until)
        return conditions


class AuditLog:
    """Writes and reads the audit table; there is no way to change a row."""

    def __init__(self, engine: AsyncEngine) -> None:
        self.engine = engine
        self._waiting: list[dict[str, Any]] = []
        self._retry: asyncio.Task[None] | None = None

    async def record(self, *entries: AuditEntry) -> None:
        """Append ``entries`` (one transaction), secrets redacted.

        When the database does not answer they wait here, in order and with their own
        times, and are written within :data:`RETRY_SECONDS` of it answering again. The
        record that found it away raises DatabaseUnavailable, for its caller to say so;
        the ones after it join the wait without trying (an action's answer waits for its
        row, and a database that drops packets would hold it for the connect timeout)."""
        now = datetime.now(UTC)
        self._waiting.extend(entry.row(now) for entry in entries)
        if self._retry is None or self._retry.done():
            await self._write()

    async def close(self) -> None:
        """Stop retrying and try once more; rows still waiting are lost, said in the log."""
        await cancel_and_wait(self._retry)
        with contextlib.suppress(DatabaseUnavailable):
            await self._write()
        await cancel_and_wait(self._retry)  # the try above, failing, scheduled another
        if self._waiting:
            log.warning(
                "%d audit rows were never written (the database did not answer), from %s "
                "to %s", len(self._waiting), self._waiting[0]["at"], self._waiting[-1]["at"],
            )  # fmt: skip

    async def _write(self) -> None:
        rows, self._waiting = self._waiting, []
        if not rows:
            return

        async def insert(conn: AsyncConnection) -> None:
            await conn.execute(audit.insert(), rows)

        try:
            await transaction(self.engine, insert)
        except DatabaseUnavailable:
            self._waiting[:0] = rows
            if self._retry is None or self._retry.done():
                self._retry = asyncio.create_task(self._retry_until_written(), name="audit")
            raise

    async def _retry_until_written(self) -> None:
        while self._waiting:
            await asyncio.sleep(RETRY_SECONDS)
            waited = len(self._waiting)
            with contextlib.suppress(DatabaseUnavailable):
                await self._write()
                log.info("%d audit rows written once the database answered again", waited)

    async def query(self, query: AuditQuery) -> tuple[int, list[dict[str, Any]]]:
        """``(total matching, the page asked for)``, newest first; rows as plain dicts."""
        conditions = query.where()
        limit = max(1, min(query.limit, MAX_LIMIT))

        async def read(conn: AsyncConnection) -> tuple[int, Sequence[Any]]:
            total = await conn.scalar(select(func.count()).select_from(audit).where(*conditions))
            rows = await conn.execute(
                select(audit)
                .where(*conditions)
                .order_by(audit.c.at.desc(), audit.c.id.desc())
                .limit(limit)
                .offset(max(0, query.offset))
            )
            return int(total or 0), rows.mappings().all()

        total, rows = await transaction(self.engine, read, write=False)
        return total, [dict(row) for row in rows]
