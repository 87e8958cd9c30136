"""KyberCore's database: the engine, its migrations and its transactions.

SQLite (WAL) in the data folder beside printers.json by default, PostgreSQL by URL for
farms that run several KyberCore processes on one database. Nothing of the domain lives
here: the job queue's tables are :mod:`kybercore.jobs.tables`, its schema history
``db/migrations/versions``.
"""

from kybercore.db.engine import default_database_url, open_database
from kybercore.db.transaction import is_unique_violation, reading, transaction
from kybercore.db.types import UTCDateTime

__all__ = [
    "UTCDateTime",
    "default_database_url",
    "is_unique_violation",
    "open_database",
    "reading",
    "transaction",
]
