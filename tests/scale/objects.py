"""What the ``kc_uploads`` object store holds: uploads must leave nothing behind."""

from __future__ import annotations

import asyncio

from nats.aio.client import Client
from nats.js.errors import NotFoundError

from kybercore.scale.broker import connect
from kybercore.scale.uploads import BUCKET


async def stored(nc: Client) -> list[str]:
    """The objects in the bucket, deleted ones aside (none when there is no bucket)."""
    try:
        bucket = await nc.jetstream().object_store(BUCKET)
        return [info.name for info in await bucket.list(ignore_deletes=True)]
    except NotFoundError:
        return []


async def stored_bytes(nc: Client) -> int:
    """What the bucket's stream holds, in bytes (deleted objects leave only small markers)."""
    bucket = await nc.jetstream().object_store(BUCKET)
    return (await bucket.status()).size


def objects_left(url: str) -> tuple[list[str], int]:
    """From a synchronous test: the objects in the bucket, and its stream's bytes."""

    async def read() -> tuple[list[str], int]:
        nc = await connect(url, "test-objects")
        try:
            return await stored(nc), await stored_bytes(nc)
        finally:
            await nc.close()

    return asyncio.run(read())
