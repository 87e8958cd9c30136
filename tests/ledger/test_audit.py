"""The audit log on SQLite and PostgreSQL: rows as recorded, filters and pages, no secret
ever stored, and no way to change or delete a row, in the code or in the database."""

from __future__ import annotations

import json
import secrets
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from hypothesis import given
from hypothesis import strategies as st
from sqlalchemy import delete, text, update
from sqlalchemy.engine import Connection
from sqlalchemy.exc import DBAPIError
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.api.auth import TOKEN_PREFIX
from kybercore.ledger.audit import REDACTED, AuditEntry, AuditLog, AuditQuery, audit, redact
from tests.jobs.conftest import database, database_url

__all__ = ["database", "database_url"]  # the fixtures, for pytest

T0 = datetime(2026, 11, 20, 12, 0, tzinfo=UTC)


def entry(n: int, **fields: Any) -> AuditEntry:
    base: dict[str, Any] = {
        "actor": "alice",
        "role": "operator",
        "action": "printer.cancel",
        "target": "printer:a",
        "params": {},
        "outcome": "ok",
        "client": "10.0.0.9",
        "request_id": f"req-{n}",
        "at": T0 + timedelta(minutes=n),
    }
    return AuditEntry(**{**base, **fields})


async def test_rows_come_back_as_recorded_newest_first_with_filters_and_pages(
    database: AsyncEngine,
) -> None:
    log = AuditLog(database)
    await log.record(
        entry(0, params={"script": "G28", "force": False, "n": 3}),
        entry(1, actor="bob", role="admin", action="printer.edit", target="printer:b"),
        entry(2, action="plate.clear", outcome="not_awaiting_clear", target="printer:a"),
        entry(3, actor="cli:root", role="admin", action="token.create", target="token:t_1"),
        entry(4, action="job.cancel", target="job:12"),
    )
    total, items = await log.query(AuditQuery())
    assert total == 5
    assert [i["request_id"] for i in items] == ["req-4", "req-3", "req-2", "req-1", "req-0"]
    first = items[-1]
    assert first["at"] == T0
    assert first["at"].tzinfo is not None
    assert first["params"] == {"script": "G28", "force": False, "n": 3}
    assert {k: first[k] for k in ("actor", "role", "action", "target", "outcome", "client")} == {
        "actor": "alice", "role": "operator", "action": "printer.cancel",
        "target": "printer:a", "outcome": "ok", "client": "10.0.0.9",
    }  # fmt: skip

    async def ids(**filters: Any) -> list[str]:
        total, rows = await log.query(AuditQuery(**filters))
        assert total == len(rows)
        return [r["request_id"] for r in rows]

    assert await ids(actor="bob") == ["req-1"]
    assert await ids(target="a") == ["req-2", "req-0"]  # the printer's id alone
    assert await ids(target="printer:a") == ["req-2", "req-0"]
    assert await ids(target="12") == ["req-4"]
    assert await ids(target="%") == []  # LIKE's wildcard is only a character here
    assert await ids(action="plate.clear") == ["req-2"]
    assert await ids(since=T0 + timedelta(minutes=1), until=T0 + timedelta(minutes=3)) == [
        "req-2", "req-1",
    ]  # fmt: skip
    total, page = await log.query(AuditQuery(limit=2, offset=2))
    assert total == 5
    assert [r["request_id"] for r in page] == ["req-2", "req-1"]


async def test_a_row_cannot_be_changed_or_deleted_even_with_sql(database: AsyncEngine) -> None:
    log = AuditLog(database)
    await log.record(entry(0))
    # No method of the log changes a row: it can append and read (and close: write what
    # waits for a database that did not answer), nothing else.
    public = {name for name in vars(AuditLog) if not name.startswith("_")}
    assert public == {"record", "query", "close"}
    for statement in (update(audit).values(actor="mallory"), delete(audit)):
        with pytest.raises(DBAPIError, match="append-only"):
            async with database.begin() as conn:
                await conn.execute(statement)
    if database.dialect.name == "postgresql":
        with pytest.raises(DBAPIError, match="append-only"):
            async with database.begin() as conn:
                await conn.execute(text("TRUNCATE audit"))
    total, items = await log.query(AuditQuery())
    assert total == 1
    assert items[0]["actor"] == "alice"


async def test_no_secret_is_ever_stored(database: AsyncEngine) -> None:
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    api_key = "mk-" + secrets.token_hex(16)
    password = "pw-" + secrets.token_hex(8)
    params = {
        "api_key": api_key,
        "apiKey": api_key,
        "token": token,
        "nested": {"Authorization": f"Bearer {token}", "password": password, "ok": "visible"},
        "list": [{"secret": api_key}, f"a note quoting {token} by mistake"],
        "moonraker_url": f"http://admin:{password}@10.0.0.5:7125",
        "script": f"M117 Bearer {api_key}",
        "cleared": {"api_key": ""},
    }
    log = AuditLog(database)
    await log.record(entry(0, params=params, target=f"printer:{api_key[:3]}"))
    async with database.connect() as conn:
        raw = [dict(row) for row in (await conn.execute(audit.select())).mappings()]
    stored = json.dumps(raw, default=str)
    for secret in (token, api_key, password):
        assert secret not in stored
    kept = raw[0]["params"]
    if isinstance(kept, str):  # a driver that hands JSON back as text
        kept = json.loads(kept)
    assert kept["api_key"] == kept["token"] == REDACTED
    assert kept["nested"]["ok"] == "visible"
    assert kept["moonraker_url"] == f"http://admin:{REDACTED}@10.0.0.5:7125"
    assert kept["cleared"] == {"api_key": ""}  # "the key was removed" is no secret


@given(
    name=st.sampled_from(["api_key", "token", "password", "Api-Key", "client_secret", "cookie"]),
    secret=st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789", min_size=8, max_size=40),
    depth=st.integers(min_value=0, max_value=4),
)
def test_a_secret_under_a_secret_name_never_survives_redaction(
    name: str, secret: str, depth: int
) -> None:
    value: Any = {name: secret}
    for level in range(depth):
        value = {f"level{level}": [value, "x"]}
    assert secret not in json.dumps(redact(value))


def _audit_drift(conn: Connection) -> list[object]:
    context = MigrationContext.configure(
        conn,
        opts={
            "include_object": lambda obj, name, kind, reflected, other: (
                (obj.table.name if kind in ("index", "column") else name) == "audit"
            )
        },
    )
    return list(compare_metadata(context, audit.metadata))


async def test_the_migration_creates_the_table_the_code_uses(database: AsyncEngine) -> None:
    async with database.connect() as conn:
        assert await conn.run_sync(_audit_drift) == []
