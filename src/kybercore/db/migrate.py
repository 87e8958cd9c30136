"""Bringing a database's schema up to date with Alembic, from inside KyberCore.

The migrations ship inside the package (``db/migrations``), so an installed KyberCore
migrates its own database on start, with no ``alembic.ini`` and no command to run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import text
from sqlalchemy.engine import Connection
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db.transaction import transaction
from kybercore.errors import ConfigError

MIGRATIONS: Final = Path(__file__).resolve().parent / "migrations"
# Two processes starting at once on one PostgreSQL database would both create the tables;
# this transaction-scoped lock makes the second wait and then find the schema current.
# (On SQLite the write transaction's lock does the same.) Any constant key will do.
_PG_LOCK_KEY: Final = 0x4B7962_6572  # "Kyber"


def alembic_config() -> Config:
    """Alembic's configuration for KyberCore's migrations (no ini file)."""
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    return config


def head_revision() -> str:
    """The newest schema revision this KyberCore knows."""
    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    assert head is not None, "db/migrations has no revisions"
    return head


async def upgrade(engine: AsyncEngine, shown: str) -> None:
    """Migrate the database to the newest revision, in one write transaction (retried
    like any other when another process holds the database).

    ``shown`` names the database in messages (its URL without the password). A database
    at a revision this KyberCore does not know was written by a newer one: that raises
    :class:`ConfigError` and changes nothing.
    """
    await transaction(engine, lambda conn: conn.run_sync(_upgrade, shown))


def _upgrade(conn: Connection, shown: str) -> None:
    if conn.dialect.name == "postgresql":
        conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _PG_LOCK_KEY})
    config = alembic_config()
    scripts = ScriptDirectory.from_config(config)
    known = {script.revision for script in scripts.walk_revisions()}
    current = MigrationContext.configure(conn).get_current_heads()
    newer = [revision for revision in current if revision not in known]
    if newer:
        raise ConfigError(
            f"The database {shown} was written by a newer KyberCore (schema revision "
            f"{', '.join(newer)}; this one knows up to {scripts.get_current_head()}). "
            "Upgrade KyberCore, or use another database."
        )
    config.attributes["connection"] = conn
    command.upgrade(config, "head")
