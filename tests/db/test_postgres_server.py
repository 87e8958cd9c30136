"""The PostgreSQL the tests start: where it listens, and what happens when it cannot run."""

from __future__ import annotations

import pytest

from kybercore.db import open_database
from kybercore.errors import ConfigError
from tests.db.postgres import PostgresServer, PostgresUnavailable, unavailable


def server_or_skip(server: PostgresServer | PostgresUnavailable) -> PostgresServer:
    if isinstance(server, PostgresUnavailable):
        unavailable(str(server))
    assert isinstance(server, PostgresServer)
    return server


def test_without_postgresql_ci_fails_and_elsewhere_skips(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="required on CI: no server here"):
        unavailable("no server here")
    monkeypatch.delenv("CI")
    with pytest.raises(pytest.skip.Exception, match="no server here"):
        unavailable("no server here")


def test_its_socket_lives_in_a_short_folder_whatever_tmpdir_is(
    postgres_server: PostgresServer | PostgresUnavailable,
) -> None:
    server = server_or_skip(postgres_server)
    socket = server.root / f".s.PGSQL.{server.port}"
    assert socket.exists()
    assert len(str(socket).encode()) < 108  # AF_UNIX's limit


async def test_a_database_that_does_not_exist_is_a_config_error(
    postgres_server: PostgresServer | PostgresUnavailable,
) -> None:
    server = server_or_skip(postgres_server)
    with pytest.raises(ConfigError, match="the database must exist") as refused:
        await open_database(server.url("no_such_database"))
    assert "no_such_database" in refused.value.message
