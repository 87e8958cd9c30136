"""KyberCore's JetStream buckets: opened, or created once (replicated on a cluster), listed,
and what their compare-and-set errors mean.

An existing bucket is always used as it is: JetStream refuses to create one again with
another configuration (error 10058), and every process must agree on a lease bucket's TTL.
On a cluster a new bucket keeps :data:`REPLICAS` copies, so losing one node of three loses
neither the registry nor a lease; a single server keeps one.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
import weakref
from collections.abc import Awaitable, Callable
from typing import Any, Final, TypeVar

from nats.aio.client import Client
from nats.errors import ConnectionReconnectingError
from nats.js import JetStreamContext
from nats.js.api import ObjectStoreConfig
from nats.js.errors import (
    APIError,
    BadRequestError,
    BucketNotFoundError,
    KeyWrongLastSequenceError,
    NotFoundError,
    ServiceUnavailableError,
)
from nats.js.kv import KeyValue
from nats.js.object_store import ObjectStore

from kybercore.errors import BrokerUnavailable

log = logging.getLogger(__name__)

REPLICAS: Final = 3
"""Copies of a new bucket on a cluster: a majority survives one node lost."""
NOT_CLUSTERED: Final = 10074
"""JetStream's "replicas > 1 not supported in non-clustered mode"."""
NO_ROOM: Final = (10005, 10023)
"""No suitable peers for the placement, or insufficient resources: fewer than REPLICAS
servers with JetStream up (a cluster starting, or one too small)."""
PLACE_WITHIN: Final = 30.0
"""How long a new bucket waits for a cluster's servers to come up."""
PLACE_RETRY: Final = 0.5
WRONG_REVISION: Final = (10071, 10164)
"""JetStream's error codes for a compare-and-set on a revision that is not the key's."""
NO_JETSTREAM: Final = (
    "No JetStream answered through the NATS server. Start nats-server with JetStream (-js); "
    "if this is a site's leaf node whose JetStream is its hub's, add ?js_domain=<the hub's "
    "domain> to KyberCore's NATS address (--nats); a worker started with --local-leases "
    "needs JetStream on that leaf node itself. A leaf node cut off from its hub answers the "
    "same: check the line to the hub. A cluster that has just started elects its JetStream "
    "leader within seconds: then try again."
)
T = TypeVar("T")
_checked: weakref.WeakKeyDictionary[Client, set[str]] = weakref.WeakKeyDictionary()
"""The object stores whose copies each connection has checked: they are opened per use."""


async def _replicated(create: Callable[[int], Awaitable[T]], bucket: str) -> T:
    """``create(replicas)`` with :data:`REPLICAS` on a cluster, one copy on a single server.

    A cluster without room for every copy is waited for (its servers may be starting), not
    settled for one copy: that bucket would stay on one server, and losing it would stop
    the fleet."""
    began = time.monotonic()
    while True:
        try:
            return await create(REPLICAS)
        except APIError as exc:
            if exc.err_code == NOT_CLUSTERED:
                return await create(1)
            if exc.err_code not in NO_ROOM:
                raise
            if time.monotonic() - began > PLACE_WITHIN:
                raise BrokerUnavailable(
                    f"The NATS cluster cannot keep {REPLICAS} copies of the {bucket} bucket "
                    f"({exc.description}). KyberCore needs at least {REPLICAS} servers with "
                    "JetStream on in a cluster: start the missing ones, then KyberCore again."
                ) from None
        await asyncio.sleep(PLACE_RETRY)


async def _check_copies(js: JetStreamContext, stream: str) -> None:
    """Warn about a bucket with fewer than :data:`REPLICAS` copies on a cluster: one made
    before KyberCore replicated its buckets, which it leaves as it is."""
    info = await js.stream_info(stream)
    copies = info.config.num_replicas or 1
    if info.cluster is not None and info.cluster.name and copies < REPLICAS:
        log.warning(
            "%s keeps %d copy on the NATS cluster %s: losing that server stops KyberCore. "
            "Raise it with: nats stream edit %s --replicas %d",
            stream, copies, info.cluster.name, stream, REPLICAS,
        )  # fmt: skip


async def key_value(js: JetStreamContext, bucket: str, **config: Any) -> KeyValue:
    """The key-value ``bucket``, created with ``config`` (nats-py's KeyValueConfig fields)
    when there is none. Every process opens one of these first, so a JetStream that does not
    answer is said here (BrokerUnavailable)."""
    try:
        kv = await js.key_value(bucket)
    except BucketNotFoundError:
        pass
    except ServiceUnavailableError as exc:
        raise BrokerUnavailable(NO_JETSTREAM) from exc
    else:
        await _check_copies(js, f"KV_{bucket}")
        return kv

    async def create(replicas: int) -> KeyValue:
        return await js.create_key_value(bucket=bucket, replicas=replicas, **config)

    with contextlib.suppress(BadRequestError):  # another process made it meanwhile
        return await _replicated(create, bucket)
    return await js.key_value(bucket)


async def lease_bucket(
    js: JetStreamContext, bucket: str, ttl: float, who: str
) -> tuple[KeyValue, float]:
    """The lease bucket ``bucket`` (created with ``ttl`` when there is none) and its TTL.

    Every process must fence by the TTL its leases expire at, which is the bucket's: a
    process started with another one follows the bucket, said once in the log. Changing it
    takes stopping every process that uses the bucket and deleting it."""
    kv = await key_value(js, bucket, ttl=ttl, history=1)
    found = (await kv.status()).ttl or ttl
    if abs(found - ttl) > 1e-3:
        log.warning(
            "%s: the %s bucket's leases last %g s (this process was given %g s); "
            "following the bucket's", who, bucket, found, ttl,
        )  # fmt: skip
    return kv, found


async def object_store(nc: Client, config: ObjectStoreConfig) -> ObjectStore:
    """The object store ``config.bucket``, created with ``config`` when absent. Looked up on
    every use (they are rare, and the broker may have restarted); its copies are checked
    once per connection.

    While ``nc`` is cut off this raises nats-py's ConnectionReconnectingError at once: a
    file's transfer is refused then, not after nats-py's request timeout."""
    bucket = config.bucket
    assert bucket is not None
    if not nc.is_connected:
        raise ConnectionReconnectingError
    js = nc.jetstream()
    try:
        store = await js.object_store(bucket)
    except NotFoundError:
        pass
    else:
        checked = _checked.setdefault(nc, set())
        if bucket not in checked:
            await _check_copies(js, f"OBJ_{bucket}")
            checked.add(bucket)
        return store

    async def create(replicas: int) -> ObjectStore:
        return await js.create_object_store(bucket, config.evolve(replicas=replicas))

    return await _replicated(create, bucket)


async def bucket_keys(js: JetStreamContext, bucket: str, prefix: str = "") -> list[str]:
    """The keys of the key-value ``bucket`` that start with ``prefix``, deleted ones
    included (their delete marker is the key's last message: reading one says so).

    Read from the stream's own count of messages per subject, in one request. nats-py's
    ``KeyValue.keys()`` watches the bucket instead, and on a busy event loop it can end
    before its first entry is read: an empty or short list, so a front found no printer to
    edit and a worker counted fewer workers than there were and claimed too many slots."""
    head = f"$KV.{bucket}."
    info = await js.stream_info(f"KV_{bucket}", subjects_filter=f"{head}{prefix}>")
    return [subject[len(head) :] for subject in info.state.subjects or {}]


def wrong_revision(exc: Exception) -> bool:
    """A compare-and-set on a key whose revision moved on (someone else wrote it). nats-py
    raises that from ``update`` as KeyWrongLastSequenceError, from ``delete`` as a bare
    BadRequestError."""
    return isinstance(exc, KeyWrongLastSequenceError) or (
        isinstance(exc, BadRequestError) and exc.err_code in WRONG_REVISION
    )
