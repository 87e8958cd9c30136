"""The queue's job files on NATS: every front keeps each file it stores in the JetStream
object store ``kc_jobfiles`` too (named by its sha256), and fetches from there a file it
does not have. A job queued on one front can then be printed by whichever front dispatches,
and the fronts need no shared disk.

A file already on a printer is queued the same way (``POST /api/jobs`` with JSON): the
front asks the printer's owner (the ``fetch_file`` command), which downloads it from its
Moonraker and stores it here under its sha256, answering only that and the size; the front
reads it back, checked, and queues it, which finds it shared already. A NATS message holds
1 MB, a G-code file hundreds: the file itself never travels in a command.

The object store keeps a file for as long as the broker keeps its stream (JetStream file
storage: broker restarts included). Files are few and rarely added, so one more copy of
each is cheap next to a lost job.
"""

from __future__ import annotations

import asyncio
import hashlib
import io
import logging
import tempfile
from pathlib import Path
from typing import Any, BinaryIO, Final

import nats.errors
from nats.aio.client import Client
from nats.js.api import ObjectMeta, ObjectMetaOptions, ObjectStoreConfig
from nats.js.errors import NotFoundError
from nats.js.object_store import ObjectStore

from kybercore.errors import FileNotFound, TransferFailed
from kybercore.fleet.service import FleetService
from kybercore.jobs.files import Content, JobFiles
from kybercore.jobs.models import JobFile
from kybercore.jobs.printers import FleetPrinters
from kybercore.scale.buckets import object_store
from kybercore.scale.uploads import CHUNK_BYTES, HashingWriter

log = logging.getLogger(__name__)

BUCKET: Final = "kc_jobfiles"


class JobFileBucket:
    """The ``kc_jobfiles`` object store on one NATS connection: files named by their
    sha256."""

    def __init__(self, nc: Client) -> None:
        self._nc = nc

    async def _bucket(self) -> ObjectStore:
        config = ObjectStoreConfig(bucket=BUCKET, description="KyberCore: the job queue's files")
        return await object_store(self._nc, config)

    async def share(self, sha256: str, source: io.BufferedIOBase, name: str) -> None:
        """Store the file read from ``source`` under ``sha256``, unless it is there already;
        TransferFailed when the broker does not take it (``name``: the file's, to say so)."""
        try:
            bucket = await self._bucket()
            if not await _has(bucket, sha256):  # else shared before: same content
                options = ObjectMetaOptions(max_chunk_size=CHUNK_BYTES)
                await bucket.put(sha256, source, meta=ObjectMeta(name=sha256, options=options))
        except (nats.errors.Error, TimeoutError) as exc:
            raise TransferFailed(
                f"The NATS broker did not take the job file '{name}' ({type(exc).__name__}), "
                "and the fronts share job files through it: nothing was queued. Try again once "
                "the broker answers."
            ) from exc

    async def fetch(self, sha256: str, target: BinaryIO) -> None:
        """Write the file stored under ``sha256`` to ``target``, checked against its name:
        FileNotFound when the broker does not have it, TransferFailed when it could not be
        read or is corrupt."""
        writer = HashingWriter(target)
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

    async def offer(self, service: FleetService, printer_id: str, path: str) -> dict[str, Any]:
        """A worker's side of the ``fetch_file`` command: download ``path`` from the
        printer as ``kybercore serve``'s queue does and store it here under its sha256,
        where the front that asked reads it (and keeps it: it becomes a job file). The
        answer is small: ``{"sha256", "size"}``; a file the printer does not have raises
        what it raises in ``serve``."""
        content = await FleetPrinters(service).download(printer_id, path)
        sha256 = await asyncio.to_thread(_sha256, content)
        # BytesIO shares the bytes it starts with: the file is in memory once.
        await self.share(sha256, io.BytesIO(content), path)
        return {"sha256": sha256, "size": len(content)}


class SharedJobFiles(JobFiles):
    """:class:`JobFiles` on this front's disk, shared with the other fronts through the
    broker's object store."""

    def __init__(self, folder: Path, nc: Client) -> None:
        super().__init__(folder)
        self._shared = JobFileBucket(nc)

    async def put(self, name: str, content: Content) -> JobFile:
        """Store the file here and in the broker; TransferFailed (and nothing queued) when
        the broker does not take it, since no other front could print it then."""
        stored = await super().put(name, content)
        handle = await asyncio.to_thread(self.path(stored.sha256).open, "rb")
        try:
            await self._shared.share(stored.sha256, handle, name)
        finally:
            await asyncio.to_thread(handle.close)
        return stored

    async def local(self, sha256: str) -> Path:
        """The file on this front's disk, fetched from the broker first when another front
        stored it."""
        path = self.path(sha256)
        if await asyncio.to_thread(path.exists):
            return path
        copy: BinaryIO = await asyncio.to_thread(tempfile.TemporaryFile)
        try:
            await self._shared.fetch(sha256, copy)
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


def _sha256(content: bytes) -> str:
    return hashlib.sha256(content).hexdigest()
