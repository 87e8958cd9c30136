"""Uploads through a front: the file crosses NATS in a JetStream object store, in chunks,
never whole in memory (G-code files can be hundreds of MB; a NATS message holds 1 MB).

1. The front streams the spooled file into the ``kc_uploads`` object store under a unique
   name, counting and hashing it as it reads (sha256).
2. It sends one ``upload`` command (:mod:`.commands`) to the printer's owner: the object's
   name, the file name, ``start``, ``confirm``, the size and the sha256.
3. The owner acknowledges at once, fetches the object into a temporary file (file I/O in
   threads), deletes the object, checks the size and sha256, and calls its
   :meth:`FleetService.upload` with the copy exactly as ``kybercore serve`` does with the
   spooled file; it answers the :class:`ActionOutcome`.
4. The front deletes the object too once the command has ended, however it ended (when the
   owner never took it, nobody else would). An object left by a process that died expires
   after :data:`TTL_SECONDS`.

How it can end, besides the outcome: nobody owns the printer (``OwnerMoving``: nothing was
uploaded); the broker is away or lost the file (``TransferFailed``: nothing reached the
printer); the copy differs from the file sent (``UploadCorrupted``: nothing uploaded or
started); no answer in time (``OutcomeUnknown``: the file may or may not be on the printer).
"""

from __future__ import annotations

import asyncio
import hashlib
import io
import logging
import tempfile
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, BinaryIO, Final

import nats.errors
from nats.aio.client import Client
from nats.js.api import ObjectMeta, ObjectMetaOptions, ObjectStoreConfig
from nats.js.errors import DigestMismatchError, NotFoundError
from nats.js.object_store import ObjectStore

from kybercore.core.paths import safe_path
from kybercore.errors import InvalidInput, TransferFailed, UploadCorrupted
from kybercore.fleet.actions import ActionOutcome
from kybercore.fleet.service import FleetService
from kybercore.scale.buckets import object_store
from kybercore.scale.commands import ANSWER_SECONDS, send_command

log = logging.getLogger(__name__)

BUCKET: Final = "kc_uploads"
TTL_SECONDS: Final = 3600.0
"""How long an object may stay in the bucket (file storage): one a process left behind when
it died expires then. An upload's object is needed for seconds to minutes."""
CHUNK_BYTES: Final = 256 * 1024
"""One chunk per NATS message: well under the broker's 1 MB max payload."""
SLOWEST_BYTES_PER_SECOND: Final = 1024 * 1024
"""The slowest transfer expected on a path a file takes (broker to worker, worker to a
printer on Wi-Fi): the waits grow with the file at this rate."""
FETCH_SECONDS: Final = 30.0
"""A worker's fetch of a small file from the broker, before the size is counted."""


def object_name() -> str:
    """A unique object name for one upload (the user's file name travels in the command)."""
    return f"upload-{uuid.uuid4().hex}"


def transfer_seconds(size: int) -> float:
    """One transfer of ``size`` bytes at the slowest rate expected."""
    return size / SLOWEST_BYTES_PER_SECOND


def answer_seconds(size: int) -> float:
    """How long a front waits for an upload's outcome once the owner took it: a command's
    time (the start that may follow) plus two transfers of the file (the owner's fetch, then
    its upload to the printer)."""
    return ANSWER_SECONDS + 2 * transfer_seconds(size)


def fetch_seconds(size: int) -> float:
    """How long a worker's fetch of the object may take before it gives up."""
    return FETCH_SECONDS + transfer_seconds(size)


@dataclass(frozen=True)
class UploadOrder:
    """The ``upload`` command's arguments: where the file waits and what it must be."""

    object: str
    size: int
    sha256: str
    filename: str
    start: bool = False
    confirm: bool = False

    def as_args(self) -> dict[str, Any]:
        """The command's ``args``."""
        return {
            "object": self.object, "size": self.size, "sha256": self.sha256,
            "filename": self.filename, "start": self.start, "confirm": self.confirm,
        }  # fmt: skip

    @classmethod
    def from_args(cls, args: Mapping[str, Any]) -> UploadOrder:
        """The order in ``args``; InvalidInput when a field is missing or of the wrong kind
        (a front of another version)."""
        try:
            order = cls(
                object=args["object"], size=args["size"], sha256=args["sha256"],
                filename=args["filename"], start=args.get("start", False),
                confirm=args.get("confirm", False),
            )  # fmt: skip
        except KeyError as exc:
            raise InvalidInput(f"The upload command lacks its '{exc.args[0]}'.") from None
        kinds = {
            "object": str, "size": int, "sha256": str, "filename": str, "start": bool,
            "confirm": bool,
        }  # fmt: skip
        for field, kind in kinds.items():
            value = getattr(order, field)
            if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
                raise InvalidInput(f"The upload command's '{field}' is not a {kind.__name__}.")
        if order.size < 0:
            raise InvalidInput("The upload command's 'size' is negative.")
        return order


def check_copy(order: UploadOrder, size: int, sha256: str, printer_id: str) -> None:
    """Raise UploadCorrupted unless the copy (``size`` bytes hashing to ``sha256``) is the
    file the order describes."""
    if size != order.size or sha256 != order.sha256:
        raise UploadCorrupted(
            f"the copy of '{order.filename}' that reached its KyberCore worker is not the "
            f"file sent ({size} bytes, sha256 {sha256[:12]}…; sent: {order.size} bytes, "
            f"sha256 {order.sha256[:12]}…). Nothing was uploaded or started; upload it again.",
            printer=printer_id,
        )


class _Counted(io.BufferedIOBase):
    """Bytes passing through, counted and hashed (sha256)."""

    def __init__(self) -> None:
        super().__init__()
        self._hash = hashlib.sha256()
        self.size = 0

    def _count(self, data: bytes | memoryview) -> None:
        self._hash.update(data)
        self.size += len(data)

    def hexdigest(self) -> str:
        """The sha256 of what passed."""
        return self._hash.hexdigest()


class HashingReader(_Counted):
    """``source`` read through, counted and hashed (the object store reads it in a thread)."""

    def __init__(self, source: BinaryIO) -> None:
        super().__init__()
        self._source = source

    def readable(self) -> bool:
        """It is."""
        return True

    def readinto(self, buffer: Any) -> int:
        """Fill ``buffer`` from the source; 0 at its end."""
        view = memoryview(buffer).cast("B")
        data = self._source.read(len(view))
        view[: len(data)] = data
        self._count(data)
        return len(data)


class HashingWriter(_Counted):
    """Writes to ``target``, counted and hashed (the object store writes in a thread)."""

    def __init__(self, target: BinaryIO) -> None:
        super().__init__()
        self._target = target

    def writable(self) -> bool:
        """It is."""
        return True

    def write(self, data: Any) -> int:
        """Write ``data`` through."""
        chunk = bytes(data)
        self._count(chunk)
        return self._target.write(chunk)


def _broker_away(printer_id: str, doing: str, exc: BaseException) -> TransferFailed:
    return TransferFailed(
        f"the NATS broker failed while {doing} ({type(exc).__name__}: {exc or 'no answer'}). "
        "Nothing reached the printer; upload the file again once the broker is back.",
        printer=printer_id,
    )


class Uploads:
    """The ``kc_uploads`` object store on one NATS connection."""

    def __init__(self, nc: Client) -> None:
        self._nc = nc

    async def _bucket(self) -> ObjectStore:
        config = ObjectStoreConfig(
            bucket=BUCKET,
            description="KyberCore: uploads on their way from a front to a worker",
            ttl=TTL_SECONDS,
        )
        return await object_store(self._nc, config)

    async def put(self, content: bytes | BinaryIO, printer_id: str) -> tuple[str, int, str]:
        """Stream ``content`` (from where it stands) into the bucket: ``(object name, size,
        sha256)``. TransferFailed when the broker does not take it."""
        source: BinaryIO = io.BytesIO(content) if isinstance(content, bytes) else content
        reader = HashingReader(source)
        name = object_name()
        meta = ObjectMeta(name=name, options=ObjectMetaOptions(max_chunk_size=CHUNK_BYTES))
        try:
            bucket = await self._bucket()
            await bucket.put(name, reader, meta=meta)
        except (nats.errors.Error, TimeoutError) as exc:
            # Chunks already stored are purged by the client, or expire with the bucket's TTL.
            raise _broker_away(printer_id, "taking the file", exc) from exc
        return name, reader.size, reader.hexdigest()

    async def fetch(self, order: UploadOrder, printer_id: str) -> BinaryIO:
        """The object copied into a temporary file (at its start), checked against
        ``order``; TransferFailed or UploadCorrupted, with nothing left behind, else."""
        copy: BinaryIO = await asyncio.to_thread(tempfile.TemporaryFile)
        try:
            writer = HashingWriter(copy)
            try:
                bucket = await self._bucket()
                async with asyncio.timeout(fetch_seconds(order.size)):
                    await bucket.get(order.object, writeinto=writer)
            except DigestMismatchError:
                # The broker's copy is not what the front stored: the check below says so.
                pass
            except NotFoundError as exc:
                raise TransferFailed(
                    f"'{order.filename}' was no longer in the broker when its KyberCore "
                    f"worker came for it ({type(exc).__name__}): it expires after "
                    f"{TTL_SECONDS:.0f} s, and a front that stopped waiting deletes it. Nothing "
                    "was uploaded or started; upload it again.",
                    printer=printer_id,
                ) from exc
            except (nats.errors.Error, TimeoutError) as exc:
                raise _broker_away(printer_id, "handing the file to its worker", exc) from exc
            check_copy(order, writer.size, writer.hexdigest(), printer_id)
            await asyncio.to_thread(copy.seek, 0)
        except BaseException:
            await asyncio.to_thread(copy.close)
            raise
        return copy

    async def discard(self, name: str) -> None:
        """Delete the object; quietly when it is gone already, or when the broker is away
        (it expires with the bucket's TTL)."""
        try:
            bucket = await self._bucket()
            await bucket.delete(name)
        except NotFoundError:
            pass
        except (nats.errors.Error, TimeoutError) as exc:
            log.warning("upload %s not deleted (%s); it expires in %.0f s", name, exc, TTL_SECONDS)

    async def receive(
        self, service: FleetService, printer_id: str, args: Mapping[str, Any]
    ) -> ActionOutcome:
        """A worker's side of the ``upload`` command: fetch and check the file, delete the
        object (whatever happened), then upload (and start) as ``kybercore serve`` does."""
        order = UploadOrder.from_args(args)
        try:
            filename = safe_path(order.filename)
            copy = await self.fetch(order, printer_id)
        finally:
            await self.discard(order.object)
        try:
            return await service.upload(
                printer_id, filename, copy, start=order.start, confirm=order.confirm
            )
        finally:
            await asyncio.to_thread(copy.close)


async def send_upload(
    nc: Client,
    printer_id: str,
    filename: str,
    content: bytes | BinaryIO,
    *,
    start: bool,
    confirm: bool,
    epoch: Callable[[], int],
) -> Any:
    """A front's side: the file into the bucket, then the ``upload`` command to the printer's
    owner; its answer (a wire-encoded outcome) or the error it raised. ``epoch()``: the slot
    epoch the front knows, read once the file is stored."""
    uploads = Uploads(nc)
    name, size, sha256 = await uploads.put(content, printer_id)
    order = UploadOrder(name, size, sha256, filename, start=start, confirm=confirm)
    check = (
        f"'{filename}' may or may not be on the printer{' (and printing)' if start else ''}: "
        "look at its file list and state before uploading it again."
    )
    try:
        return await send_command(
            nc, printer_id, "upload", order.as_args(), epoch=epoch(),
            answer_timeout=answer_seconds(size), check=check,
        )  # fmt: skip
    finally:
        await uploads.discard(name)
