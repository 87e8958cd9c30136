"""The database: opened and migrated from nothing, reopened as it was, refused with a
clear message when it cannot be used; SQLite's settings on every connection."""

from __future__ import annotations

import asyncio
import logging
import sqlite3
from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import MetaData, text
from sqlalchemy.engine import Connection
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine

from kybercore.db import default_database_url, open_database, transaction
from kybercore.db import engine as db_engine
from kybercore.db.migrate import head_revision
from kybercore.errors import ConfigError
from kybercore.jobs.models import JobFile, NewJob
from kybercore.jobs.store import JobStore
from kybercore.jobs.tables import metadata as queue_tables
from kybercore.ledger.audit import metadata as audit_tables
from kybercore.ledger.tables import metadata as ledger_tables
from kybercore.notify.tables import metadata as notify_tables
from kybercore.sim.stack import free_port

NEW = NewJob(JobFile("0" * 64, "cube.gcode", 100), quantity=2)


def _every_table() -> MetaData:
    """The tables of every part that owns some (queue, ledger, audit, notifications), as one
    schema."""
    schema = MetaData()
    for part in (queue_tables, ledger_tables, audit_tables, notify_tables):
        for table in part.tables.values():
            table.to_metadata(schema)
    return schema


def _schema_drift(conn: Connection) -> list[object]:
    return list(compare_metadata(MigrationContext.configure(conn), _every_table()))


async def test_an_empty_database_is_migrated_to_the_schema_the_code_uses(
    database: AsyncEngine,
) -> None:
    async with database.connect() as conn:
        assert await conn.run_sync(_schema_drift) == []
        version = await conn.scalar(text("SELECT version_num FROM alembic_version"))
    assert version == head_revision()


async def test_reopening_keeps_the_data_and_migrates_nothing(database_url: str) -> None:
    engine = await open_database(database_url)
    job = await JobStore(engine).create_job(NEW, "ana")
    await engine.dispose()
    engine = await open_database(database_url)
    try:
        assert (await JobStore(engine).job(job.id)).file.name == "cube.gcode"
    finally:
        await engine.dispose()


async def test_two_processes_opening_a_new_database_at_once_both_get_it(
    database_url: str,
) -> None:
    # Two engines stand for two KyberCore processes: both try to migrate the empty database.
    engines = await asyncio.gather(open_database(database_url), open_database(database_url))
    try:
        for engine in engines:
            assert await JobStore(engine).jobs() == []
    finally:
        for engine in engines:
            await engine.dispose()


async def test_a_database_written_by_a_newer_kybercore_is_refused(database_url: str) -> None:
    engine = await open_database(database_url)
    async with engine.begin() as conn:
        await conn.execute(text("UPDATE alembic_version SET version_num = '9999'"))
    await engine.dispose()
    with pytest.raises(ConfigError, match="newer KyberCore") as refused:
        await open_database(database_url)
    assert "9999" in refused.value.message
    assert "Upgrade KyberCore" in refused.value.message


@pytest.mark.parametrize(
    ("url", "says"),
    [
        ("not a url", "not a URL"),
        ("mysql://kc:pw@localhost/kc", "cannot use a 'mysql' database"),
        ("sqlite+aiosqlite://", "needs a file"),
        ("sqlite:///:memory:", "needs a file"),
    ],
)
async def test_a_url_kybercore_cannot_use_is_a_config_error(url: str, says: str) -> None:
    with pytest.raises(ConfigError, match=says):
        await open_database(url)


async def test_an_unreachable_postgresql_server_is_a_config_error_without_the_password() -> None:
    port = free_port()  # nothing listens there
    with pytest.raises(ConfigError) as refused:
        await open_database(f"postgresql://kc:s3cret@127.0.0.1:{port}/queue")
    message = refused.value.message
    assert f"127.0.0.1:{port}/queue" in message
    assert "s3cret" not in message
    assert "server runs" in message


async def test_an_sqlite_file_in_a_missing_folder_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="folder exists"):
        await open_database(default_database_url(tmp_path / "missing"))


def test_the_default_database_is_kybercore_db_beside_printers_json(tmp_path: Path) -> None:
    url = default_database_url(tmp_path)
    assert url == f"sqlite+aiosqlite:///{tmp_path}/kybercore.db"
    assert db_engine.parse_database_url("sqlite:///x.db").drivername == "sqlite+aiosqlite"
    assert db_engine.parse_database_url("postgres://h/d").drivername == "postgresql+asyncpg"


async def test_every_sqlite_connection_has_wal_foreign_keys_and_a_busy_timeout(
    tmp_path: Path,
) -> None:
    engine = await open_database(default_database_url(tmp_path))
    try:
        async with engine.connect() as conn:
            pragmas = [
                await conn.scalar(text(f"PRAGMA {name}"))
                for name in ("journal_mode", "foreign_keys", "busy_timeout", "synchronous")
            ]
        assert pragmas == ["wal", 1, db_engine.BUSY_TIMEOUT_MS, 2]
    finally:
        await engine.dispose()


async def test_an_sqlite_write_transaction_holds_the_write_lock_from_its_begin(
    tmp_path: Path,
) -> None:
    engine = await open_database(default_database_url(tmp_path))
    other = sqlite3.connect(tmp_path / "kybercore.db", timeout=0, isolation_level=None)

    async def try_other_writer(conn: AsyncConnection) -> str:
        # Nothing written yet in this transaction, and still no other writer may begin.
        try:
            other.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            return str(exc)
        other.execute("ROLLBACK")
        return "began"

    try:
        assert await transaction(engine, try_other_writer) == "database is locked"
        assert await transaction(engine, try_other_writer, write=False) == "began"
    finally:
        other.close()
        await engine.dispose()


async def test_a_write_that_finds_the_database_locked_is_run_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Another process holds SQLite's write lock past the busy timeout: the transaction
    is retried, and commits once the lock is free."""
    monkeypatch.setattr(db_engine, "BUSY_TIMEOUT_MS", 50)
    engine = await open_database(default_database_url(tmp_path))
    holder = sqlite3.connect(tmp_path / "kybercore.db", isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    tries: list[int] = []

    class ReleaseOnRetry(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if holder.in_transaction:
                holder.execute("COMMIT")  # the other process finishes, after one failure

    async def write(conn: AsyncConnection) -> int:
        tries.append(1)
        return (await conn.execute(text("DELETE FROM settings"))).rowcount

    handler = ReleaseOnRetry(logging.WARNING)
    logging.getLogger("kybercore.db.transaction").addHandler(handler)
    try:
        assert await transaction(engine, write) == 0
    finally:
        logging.getLogger("kybercore.db.transaction").removeHandler(handler)
        holder.close()
        await engine.dispose()
    assert len(tries) == 1  # the first try never began: BEGIN IMMEDIATE timed out
