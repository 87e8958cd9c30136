"""A real PostgreSQL server for tests, from Debian's ``postgresql`` package.

Started once per test session in a temporary directory, on a free loopback port, as the
``postgres`` OS user (or ``nobody``) when the tests run as root, since postgres refuses
root; stopped by its PID. Each test gets an empty database of its own.
"""

from __future__ import annotations

import itertools
import os
import pwd
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Final

import pytest

from kybercore.sim.stack import free_port

USER: Final = "kybercore"
# The server's unix socket lives here too: /tmp/kc-pg-XXXXXXXX/.s.PGSQL.N stays far below
# AF_UNIX's 108 bytes even when $TMPDIR is a long CI path.
_ROOT: Final = "/tmp"
_READY_WITHIN: Final = 60.0
_STOP_WITHIN: Final = 30.0
_EMPTY: Final = (
    "SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
    "WHERE datname = current_database() AND pid <> pg_backend_pid(); "
    "DROP SCHEMA public CASCADE; CREATE SCHEMA public;"
)


class PostgresUnavailable(Exception):
    """PostgreSQL could not be started here; the message says why."""


def bin_dir() -> Path:
    """The newest ``/usr/lib/postgresql/<version>/bin`` that has a server."""
    found = sorted(
        Path("/usr/lib/postgresql").glob("*/bin/postgres"),
        key=lambda path: int(path.parent.parent.name) if path.parent.parent.name.isdigit() else 0,
    )
    if not found:
        raise PostgresUnavailable(
            "PostgreSQL is not installed (no /usr/lib/postgresql/*/bin/postgres); "
            "install Debian's postgresql package (scripts/bootstrap.sh --test does)."
        )
    return found[-1].parent


class PostgresServer:
    """One postgres process and the databases made on it."""

    def __init__(self) -> None:
        self.bin = bin_dir()
        self.root = Path(tempfile.mkdtemp(prefix="kc-pg-", dir=_ROOT))
        self.port = 0
        self.process: subprocess.Popen[bytes] | None = None
        self._log = self.root / "postgres.log"
        self._names = itertools.count(1)
        self._spare: list[str] = []
        self._as_user: list[str] = []
        if os.getuid() == 0:
            account = _service_account()
            os.chown(self.root, account.pw_uid, account.pw_gid)
            self._as_user = [
                "setpriv", f"--reuid={account.pw_uid}", f"--regid={account.pw_gid}",
                "--clear-groups", "--",
            ]  # fmt: skip

    def start(self) -> None:
        """initdb, then postgres; returns once it accepts connections."""
        data = self.root / "data"
        self._run(
            str(self.bin / "initdb"), "-D", str(data), "-U", USER, "--auth=trust",
            "-E", "UTF8", "--locale=C", "--no-sync",
        )  # fmt: skip
        for _ in range(3):  # a port free a moment ago may be taken by now
            self.port = free_port()
            with self._log.open("ab") as log:
                self.process = subprocess.Popen(
                    [
                        *self._as_user, str(self.bin / "postgres"), "-D", str(data),
                        "-k", str(self.root), "-p", str(self.port),
                        "-c", "listen_addresses=127.0.0.1",
                        # Test data: speed over durability.
                        "-c", "fsync=off", "-c", "synchronous_commit=off",
                        "-c", "full_page_writes=off",
                    ],
                    stdout=log, stderr=subprocess.STDOUT, cwd=self.root,
                )  # fmt: skip
            if self._wait_ready():
                return
        raise PostgresUnavailable(f"postgres did not start:\n{self._tail()}")

    def stop(self) -> None:
        """Fast shutdown by PID, then remove everything."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(_STOP_WITHIN)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        shutil.rmtree(self.root, ignore_errors=True)

    def create_database(self) -> str:
        """An empty database; its SQLAlchemy URL. Give it back with :meth:`recycle`."""
        if self._spare:
            return self.url(self._spare.pop())
        name = f"kc_test_{next(self._names)}"
        self._client("createdb", name)
        return self.url(name)

    def recycle(self, url: str) -> None:
        """Empty a database from :meth:`create_database` for the next test: its
        connections ended, its schema dropped (four times faster than a new database)."""
        name = url.rsplit("/", 1)[1]
        self._client("psql", "-q", "-v", "ON_ERROR_STOP=1", "-d", name, "-c", _EMPTY)
        self._spare.append(name)

    def url(self, database: str) -> str:
        """The asyncpg URL of ``database`` on this server."""
        return f"postgresql+asyncpg://{USER}@127.0.0.1:{self.port}/{database}"

    def _client(self, program: str, *args: str) -> None:
        self._run(
            str(self.bin / program), "-h", "127.0.0.1", "-p", str(self.port), "-U", USER, *args
        )

    def _run(self, *command: str) -> None:
        done = subprocess.run(
            [*self._as_user, *command], cwd=self.root, capture_output=True, text=True, check=False
        )
        if done.returncode != 0:
            raise PostgresUnavailable(f"{' '.join(command)} failed:\n{done.stdout}{done.stderr}")

    def _wait_ready(self) -> bool:
        assert self.process is not None
        deadline = time.monotonic() + _READY_WITHIN
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                return False
            ready = subprocess.run(
                [str(self.bin / "pg_isready"), "-q", "-h", "127.0.0.1", "-p", str(self.port)],
                check=False,
            )
            if ready.returncode == 0:
                return True
            time.sleep(0.1)  # poll: the deadline above bounds the wait
        raise PostgresUnavailable(f"postgres not ready after {_READY_WITHIN:g} s:\n{self._tail()}")

    def _tail(self) -> str:
        try:
            return "\n".join(self._log.read_text(errors="replace").splitlines()[-20:])
        except OSError:
            return "(no log)"


def _service_account() -> pwd.struct_passwd:
    for name in ("postgres", "nobody"):
        try:
            return pwd.getpwnam(name)
        except KeyError:
            continue
    raise PostgresUnavailable("running as root and neither a 'postgres' nor a 'nobody' user")


def unavailable(reason: str) -> None:
    """Fail on CI, where PostgreSQL must run; skip elsewhere."""
    if os.environ.get("CI") == "true":
        pytest.fail(f"PostgreSQL is required on CI: {reason}")
    pytest.skip(f"PostgreSQL unavailable: {reason}")
