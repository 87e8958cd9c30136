"""Alembic's entry point: migrate the connection KyberCore hands over.

:func:`kybercore.db.migrate.upgrade` opens the transaction and passes its connection in
``config.attributes``; there is no offline (SQL script) mode and no ``alembic.ini``.
"""

from __future__ import annotations

from alembic import context

connection = context.config.attributes["connection"]
context.configure(connection=connection, target_metadata=None)
with context.begin_transaction():
    context.run_migrations()
