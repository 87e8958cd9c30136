"""The queue's job files on NATS: every front keeps each file it stores in the JetStream
object store ``kc_jobfiles`` too (named by its sha256), and fetches from there a file it
does not have. A job queued on one front can then be printed by whichever front dispatches,
and the fronts need no shared disk.

The object store keeps a file for as long as the broker keeps its stream (JetStream file
storage: broker restarts included). Files are few and rarely added, so one more copy of
each is cheap next to a lost job.
"""

from __future__ import annotations

import asyncio
import logging
import tempfile
from pathlib import Path
from typing import BinaryIO, Final

import nats.errors
from nats.aio.client import Client
from nats.js.api import ObjectMeta, ObjectMetaOptions, ObjectStoreConfig
from nats.js.errors import NotFoundError
from nats.js.object_store import ObjectStore

from kybercore.errors import FileNotFound, TransferFailed
from kybercore.jobs.files import Content, JobFiles
from kybercore.jobs.models import JobFile
from kybercore.scale.broker import object_store
from kybercore.scale.uploads import CHUNK_BYTES, HashingWriter

log = logging.getLogger(__name__)

BUCKET: Final = "kc_jobfiles"


class SharedJobFiles(JobFiles):
    """:class:`JobFiles` on this front's disk, shared with the other fronts through the
    broker's object store."""

    def __init__(self, folder: Path, nc: Client) -> None:
        super().__init__(folder)
        self._nc = nc

    async def _bucket(self) -> ObjectStore:
        config = ObjectStoreConfig(bucket=BUCKET, description="KyberCore: the job queue's files")
        return await object_store(self._nc, config)

    async def put(self, name: str, content: Content) -> JobFile:
        """Store the file here and in the broker; TransferFailed (and nothing queued) when
        the broker does not take it, since no other front could print it then."""
        stored = await super().put(name, content)
        try:
            bucket = await self._bucket()
            if not await _has(bucket, stored.sha256):  # else shared before: same content
                handle = await asyncio.to_thread(self.path(stored.sha256).open, "rb")
                try:
                    options = ObjectMetaOptions(max_chunk_size=CHUNK_BYTES)
                    meta = ObjectMeta(name=stored.sha256, options=options)
                    await bucket.put(stored.sha256, handle, meta=meta)
                finally:
                    await asyncio.to_thread(handle.close)
        except (nats.errors.Error, TimeoutError) as exc:
            raise TransferFailed(
                f"The NATS broker did not take the job file '{name}' ({type(exc).__name__}), "
                "so no other front could print it: nothing was queued. Try again once the "
                "broker answers."
            ) from exc
        return stored

    async def local(self, sha256: str) -> Path:
        """The file on this front's disk, fetched from the broker first when another front
        stored it."""
        path = self.path(sha256)
        if await asyncio.to_thread(path.exists):
            return path
        copy: BinaryIO = await asyncio.to_thread(tempfile.TemporaryFile)
        try:
            writer = HashingWriter(copy)
            try:
                bucket = await self._bucket()
                await bucket.get(sha256, writeinto=writer)
            except NotFoundError as exc:
                raise FileNotFound(
                    f"No front has the job file {sha256} any more (not in the broker's "
                    "kc_jobfiles either); queue the job again with its file."
                ) from exc
            except (nats.errors.Error, TimeoutError) as exc:
                raise TransferFailed(
                    f"The job file {sha256} could not be fetched from the NATS broker "
                    f"({type(exc).__name__}); the next try may."
                ) from exc
            if writer.hexdigest() != sha256:
                raise TransferFailed(
                    f"The broker's copy of job file {sha256} is corrupt (its sha256 is "
                    f"{writer.hexdigest()}); queue the job again with its file."
                )
            await asyncio.to_thread(copy.seek, 0)
            await super().put(sha256, copy)
        finally:
            await asyncio.to_thread(copy.close)
        log.info("job file %s fetched from the broker", sha256)
        return path


async def _has(bucket: ObjectStore, name: str) -> bool:
    try:
        await bucket.get_info(name)
    except NotFoundError:
        return False
    return True
