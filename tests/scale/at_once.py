"""Refused "at once": a broker gone is said without waiting for nats-py's 5-s timeout, a
product promise the tests time (and print, for ``bench/README.md``'s table)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from typing import Final

from nats.aio.client import Client

from kybercore.scale.broker import LocalServer
from tests.helpers import wait_for

REFUSED_WITHIN: Final = 1.0
"""A refusal "at once", in seconds (it takes well under a millisecond)."""


async def cut_off(server: LocalServer, nc: Client, who: str) -> None:
    """Stop ``server`` and wait until ``nc`` (the ``who``'s connection) sees it gone: a
    call made then meets a client that knows, not one still finding out."""
    server.stop()
    await wait_for(lambda: not nc.is_connected, 10, f"the {who} to see the broker gone")


@contextlib.contextmanager
def at_once(what: str) -> Iterator[None]:
    """The block must end within REFUSED_WITHIN; ``what`` names it in the printed figure.
    Put ``pytest.raises`` inside it, so the refusal's own time is what is timed."""
    began = time.monotonic()
    yield
    took = time.monotonic() - began
    print(f"{what} in {took * 1000:.2f} ms")
    assert took < REFUSED_WITHIN
