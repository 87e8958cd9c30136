"""The database fixtures of tests/jobs (one SQLite file or PostgreSQL database per test)."""

from tests.jobs.conftest import database, database_url

__all__ = ["database", "database_url"]
