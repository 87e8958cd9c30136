"""Opening KyberCore's database: SQLite beside printers.json by default, PostgreSQL by URL.

:func:`open_database` gives back an engine whose schema is current (it runs the migrations)
or raises :class:`~kybercore.errors.ConfigError` saying what is wrong with the URL or the
database, never a driver's stack trace.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Final

from sqlalchemy import event
from sqlalchemy.engine import URL, Connection, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError
from sqlalchemy.ext.asyncio import AsyncEngine, create_async_engine

from kybercore.db.migrate import upgrade
from kybercore.db.transaction import WRITE_OPTION
from kybercore.errors import ConfigError, DatabaseUnavailable, KyberCoreError

log = logging.getLogger(__name__)

# The async driver for each database KyberCore speaks to, by the names people write.
_DRIVERS: Final = {
    "sqlite": "sqlite+aiosqlite",
    "sqlite+aiosqlite": "sqlite+aiosqlite",
    "postgresql": "postgresql+asyncpg",
    "postgres": "postgresql+asyncpg",
    "postgresql+asyncpg": "postgresql+asyncpg",
}
_EXAMPLES: Final = (
    "sqlite+aiosqlite:////path/to/kybercore.db or "
    "postgresql+asyncpg://user:password@host:5432/database"
)
# How long an SQLite writer waits for another one (another process) before "database is
# locked"; a queue transaction takes milliseconds, so this only runs out when one hangs.
BUSY_TIMEOUT_MS: Final = 10_000
# How long to wait for a PostgreSQL server to accept the connection.
CONNECT_TIMEOUT: Final = 10.0


def default_database_url(folder: Path) -> str:
    """The built-in database: ``kybercore.db`` (SQLite) in ``folder``, the one that holds
    printers.json."""
    return f"sqlite+aiosqlite:///{(folder / 'kybercore.db').absolute()}"


def parse_database_url(url: str) -> URL:
    """``url`` with its async driver, or :class:`ConfigError` for one KyberCore cannot use.

    ``sqlite:///…`` and ``postgresql://…`` are accepted for their async drivers.
    """
    try:
        parsed = make_url(url)
    except ArgumentError:
        # Not echoed: an unparsable URL may still hold a password.
        raise ConfigError(f"The database URL is not a URL. Write it as {_EXAMPLES}.") from None
    driver = _DRIVERS.get(parsed.drivername)
    if driver is None:
        raise ConfigError(
            f"KyberCore cannot use a '{parsed.drivername}' database: it speaks to SQLite and "
            f"PostgreSQL. Write the URL as {_EXAMPLES}."
        )
    if driver.startswith("sqlite") and parsed.database in (None, "", ":memory:"):
        raise ConfigError(
            "An SQLite database URL needs a file (a database in memory would lose the queue "
            f"on every restart). Write it as {_EXAMPLES}."
        )
    return parsed.set(drivername=driver)


async def open_database(url: str) -> AsyncEngine:
    """An engine on ``url`` with the schema migrated to the newest revision.

    SQLite gets WAL, a busy timeout and foreign keys on every connection, and takes its
    write lock when a write transaction begins (see :func:`kybercore.db.transaction`).
    Raises :class:`ConfigError` for a bad URL, a database that cannot be reached or
    opened, or one written by a newer KyberCore.
    """
    parsed = parse_database_url(url)
    shown = parsed.render_as_string(hide_password=True)
    engine = _create_engine(parsed)
    try:
        await upgrade(engine, shown)
    except DatabaseUnavailable as exc:
        await engine.dispose()
        raise ConfigError(_unreachable(parsed, shown, exc.__cause__ or exc)) from exc
    except KyberCoreError:
        await engine.dispose()
        raise
    except DBAPIError as exc:  # refused: a wrong password, a database that does not exist
        await engine.dispose()
        raise ConfigError(_unreachable(parsed, shown, exc)) from exc
    log.info("Database %s is ready", shown)
    return engine


def _create_engine(url: URL) -> AsyncEngine:
    if url.get_backend_name() == "sqlite":
        engine = create_async_engine(url)
        event.listen(engine.sync_engine, "connect", _sqlite_connect)
        event.listen(engine.sync_engine, "begin", _sqlite_begin)
        return engine
    return create_async_engine(
        url,
        pool_pre_ping=True,  # a restarted server leaves dead connections in the pool
        connect_args={
            "timeout": CONNECT_TIMEOUT,
            "server_settings": {"application_name": "kybercore"},
        },
    )


def _sqlite_connect(dbapi_connection: Any, _record: Any) -> None:
    # The sqlite3 module's own transaction handling would not BEGIN before a SELECT or DDL;
    # turn it off and let _sqlite_begin say BEGIN (SQLAlchemy's documented recipe).
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    try:
        # busy_timeout first: switching to WAL waits for the lock like any writer.
        cursor.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        cursor.execute("PRAGMA journal_mode = WAL")
        cursor.execute("PRAGMA foreign_keys = ON")
        # FULL: a committed clear or verdict survives a power cut, not only a crash.
        cursor.execute("PRAGMA synchronous = FULL")
    finally:
        cursor.close()


def _sqlite_begin(conn: Connection) -> None:
    # A writer takes the write lock at BEGIN: two writers then queue on busy_timeout instead
    # of both reading and one failing at its first write ("database is locked" that no
    # waiting can cure). Readers begin deferred and never wait in WAL.
    write = conn.get_execution_options().get(WRITE_OPTION, False)
    conn.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")


def _unreachable(url: URL, shown: str, exc: BaseException) -> str:
    cause = getattr(exc, "orig", None) or exc
    detail = (str(cause).strip().splitlines() or [type(cause).__name__])[0]
    if url.get_backend_name() == "sqlite":
        advice = "Check that its folder exists and that KyberCore may write there."
    else:
        advice = (
            "Check that the PostgreSQL server runs and accepts connections, and that the "
            "URL's user, password, host, port and database are right (the database must "
            "exist)."
        )
    return f"Cannot open the database {shown}: {detail}. {advice}"
