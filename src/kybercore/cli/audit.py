"""The command line's changes in the audit log, like the API's.

``kybercore printers add|edit|remove`` and ``kybercore tokens create|revoke`` change the
fleet and who may use it, so they are recorded as the API's actions are, with the actor
``cli:<OS user>`` and the role ``admin`` (whoever may write printers.json holds every
right). The database is the server's: ``$KYBERCORE_DATABASE_URL``, else ``kybercore.db``
beside printers.json. It is opened after the change: the command line is also how an
admin repairs a fleet whose server or database is broken, so a database that cannot be
opened does not stop the change; the command says it went unrecorded.
"""

from __future__ import annotations

import asyncio
import gc
import getpass
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from rich.text import Text

from kybercore.cli.output import err
from kybercore.errors import ConfigError, KyberCoreError
from kybercore.registry.store import default_printers_path

if TYPE_CHECKING:
    from sqlalchemy.ext.asyncio import AsyncEngine

DATABASE_URL_ENV: Final = "KYBERCORE_DATABASE_URL"


@dataclass
class CliAction:
    """What a command records; it fills in the target once it knows it (a new id)."""

    action: str
    target: str = ""
    params: dict[str, Any] = field(default_factory=dict)


def database_url(printers_file: Path | None) -> str:
    """The database the server of ``printers_file`` uses."""
    from kybercore.db import default_database_url

    folder = (printers_file or default_printers_path()).absolute().parent
    return os.environ.get(DATABASE_URL_ENV) or default_database_url(folder)


def cli_actor() -> str:
    """``cli:<the OS user running the command>``."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):  # no name for this uid (a bare container)
        user = f"uid{os.getuid()}"
    return f"cli:{user}"


@contextmanager
def audited(printers_file: Path | None, action: CliAction) -> Iterator[CliAction]:
    """Run the block, then record it with its outcome: ``ok``, or the code of the
    :class:`KyberCoreError` it raised (raised on). A change that went through but could not
    be recorded (the database cannot be opened) is said on stderr, and stays made."""
    outcome = "internal_error"
    try:
        yield action
        outcome = "ok"
    except KyberCoreError as exc:
        outcome = exc.code
        raise
    finally:
        try:
            asyncio.run(_record(database_url(printers_file), action, outcome))
        except Exception as exc:
            if outcome == "ok":
                why = exc.message if isinstance(exc, KyberCoreError) else repr(exc)
                err.print(
                    Text(f"Warning: done, but the audit log did not record it: {why}", "yellow")
                )


async def _record(url: str, action: CliAction, outcome: str) -> None:
    # Here, not at the top: SQLAlchemy and Alembic are for the commands that change things.
    from kybercore.ledger.audit import AuditEntry, AuditLog

    engine = await _open(url)
    try:
        entry = AuditEntry(
            actor=cli_actor(),
            role="admin",
            action=action.action,
            target=action.target,
            params=action.params,
            outcome=outcome,
            client="local",
            request_id=uuid.uuid4().hex,
        )
        await AuditLog(engine).record(entry)
    finally:
        await engine.dispose()


async def _open(url: str) -> AsyncEngine:
    from kybercore.db import open_database

    why = ""
    try:
        return await open_database(url)
    except KyberCoreError as exc:
        why = exc.message
    # The failed SQLite connection's worker thread reports its end to this event loop:
    # collect it while the loop still runs (asyncio.run closes the loop on return).
    gc.collect()
    raise ConfigError(why)
