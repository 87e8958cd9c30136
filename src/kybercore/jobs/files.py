"""The queue's own copy of each job file, named by its content, with its slicer metadata.

A file is stored once as ``<folder>/<sha256>.gcode``, whatever it was called and however
often it was queued: the content is streamed to a temporary file in the same folder while
it is hashed, then renamed into place, so a reader never sees half a file and an upload that
fails leaves nothing behind. Disk work runs in threads (``asyncio.to_thread``), never on the
event loop.

Metadata comes from Moonraker's own parser (``components/file_manager/metadata.py`` of the
Moonraker runtime, :data:`kybercore.sim.runtime.MOONRAKER`), run as a subprocess: the queue
then judges a file exactly as a printer's Moonraker will describe it. The parser writes the
file's thumbnails to ``<folder>/.thumbs/<sha256>-<w>x<h>.png``. A file it cannot read (or a
parser that is missing, fails or hangs) gets empty metadata and a logged warning, never an
error: validation then treats the file as one without metadata.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import logging
import os
import re
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import IO, Any, BinaryIO, Final

from kybercore.errors import FileNotFound, InvalidInput
from kybercore.jobs.models import JobFile
from kybercore.sim.runtime import MOONRAKER

log = logging.getLogger(__name__)

CHUNK: Final = 1024 * 1024
PARSE_TIMEOUT: Final = 60.0
"""Seconds the parser may take; it reads a file's header and footer, not all of it."""
GRACE: Final = 3600.0
"""Seconds a file is spared by :meth:`JobFiles.remove_unused` after it was last put: its
job may not be stored yet. A temporary file this old is debris of a crash."""
_SHA256: Final = re.compile(r"[0-9a-f]{64}")
_TEMP_PREFIX: Final = ".upload-"
# What the parser says about the copy on disk rather than the content: left out, so the
# same content always has the same metadata.
_NOT_CONTENT: Final = ("uuid", "modified")
_FIND_PARSER: Final = "import moonraker, os; print(os.path.dirname(moonraker.__file__))"
_parsers: dict[Path, Path] = {}
"""Moonraker interpreter -> its metadata.py, found once per process."""

Content = bytes | AsyncIterator[bytes] | BinaryIO


class JobFiles:
    """The job files in ``folder`` (created on first use)."""

    def __init__(self, folder: Path, *, parse_timeout: float = PARSE_TIMEOUT) -> None:
        self.folder = folder
        self.parse_timeout = parse_timeout
        self._writing: set[Path] = set()

    def path(self, sha256: str) -> Path:
        """Where the file with this content lives (it may not exist)."""
        if not _SHA256.fullmatch(sha256):
            raise InvalidInput(f"'{sha256}' is not a sha256: 64 lowercase hexadecimal digits.")
        return self.folder / f"{sha256}.gcode"

    async def put(self, name: str, content: Content) -> JobFile:
        """Store ``content`` (bytes, chunks, or a binary file read from where it stands) and
        read its metadata. The same content twice is one file."""
        temp = await asyncio.to_thread(self._new_temp)
        self._writing.add(temp)
        try:
            out = await asyncio.to_thread(temp.open, "wb")
            try:
                digest, size = await _copy(content, out)
                await asyncio.to_thread(_flush, out)
            finally:
                await asyncio.to_thread(out.close)
            sha256 = digest.hexdigest()
            await asyncio.to_thread(_settle, temp, self.path(sha256))
        except BaseException:
            await asyncio.to_thread(temp.unlink, missing_ok=True)
            raise
        finally:
            self._writing.discard(temp)
        meta = await self.metadata(sha256)
        return JobFile(sha256=sha256, name=name, size=size, meta=meta)

    async def local(self, sha256: str) -> Path:
        """The stored file on this machine, to be read (reading fails if it is gone)."""
        return self.path(sha256)

    async def open(self, sha256: str) -> BinaryIO:
        """The stored file, open for reading (the caller closes it)."""
        path = self.path(sha256)
        try:
            return await asyncio.to_thread(path.open, "rb")
        except FileNotFoundError:
            raise FileNotFound(
                f"KyberCore no longer has the job file {sha256}; queue the job again with its file."
            ) from None

    async def metadata(self, sha256: str) -> dict[str, Any]:
        """The stored file's metadata as Moonraker's parser reads it; ``{}`` when it cannot."""
        path = self.path(sha256)
        try:
            parser = await _parser(self.parse_timeout)
            out = await _run(
                [str(MOONRAKER.python), str(parser), "-f", path.name, "-p", str(self.folder)],
                self.parse_timeout,
            )
            meta = json.loads(out)["metadata"]
            if not isinstance(meta, dict):
                raise TypeError(f"metadata is a {type(meta).__name__}")  # noqa: TRY301
        except (OSError, ValueError, KeyError, TypeError, TimeoutError) as exc:
            log.warning("No metadata for job file %s: %s", sha256, exc)
            return {}
        return {key: value for key, value in meta.items() if key not in _NOT_CONTENT}

    async def remove_unused(self, keep: set[str]) -> list[str]:
        """Delete every stored file whose sha256 is not in ``keep`` and that was not put in
        the last :data:`GRACE` seconds, its thumbnails, and temporary files left by a crash;
        return the sha256s removed."""
        return await asyncio.to_thread(self._remove_unused, keep)

    def _new_temp(self) -> Path:
        self.folder.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(dir=self.folder, prefix=_TEMP_PREFIX, suffix=".part")
        os.close(fd)
        return Path(name)

    def _remove_unused(self, keep: set[str]) -> list[str]:
        if not self.folder.is_dir():
            return []
        old = time.time() - GRACE
        removed = []
        for path in self.folder.glob("*.gcode"):
            with contextlib.suppress(FileNotFoundError):
                if path.stem not in keep and _SHA256.fullmatch(path.stem) and _older(path, old):
                    path.unlink()
                    removed.append(path.stem)
        thumbs = self.folder / ".thumbs"
        for thumb in thumbs.glob("*") if thumbs.is_dir() else ():
            if thumb.name.split("-", 1)[0] in removed:
                thumb.unlink(missing_ok=True)
        for temp in self.folder.glob(f"{_TEMP_PREFIX}*.part"):
            with contextlib.suppress(FileNotFoundError):
                if temp not in self._writing and _older(temp, old):
                    temp.unlink()
        return sorted(removed)


def _older(path: Path, than: float) -> bool:
    return path.stat().st_mtime < than


async def _copy(content: Content, out: IO[bytes]) -> tuple[Any, int]:
    """Write ``content`` to ``out`` while hashing it; the hash and the size."""
    digest = hashlib.sha256()
    if isinstance(content, bytes):
        await asyncio.to_thread(_write, digest, out, content)
        return digest, len(content)
    if isinstance(content, AsyncIterator):
        size = 0
        async for chunk in content:
            await asyncio.to_thread(_write, digest, out, chunk)
            size += len(chunk)
        return digest, size
    return digest, await asyncio.to_thread(_copy_file, digest, content, out)


def _write(digest: Any, out: IO[bytes], chunk: bytes) -> None:
    digest.update(chunk)
    out.write(chunk)


def _copy_file(digest: Any, source: BinaryIO, out: IO[bytes]) -> int:
    size = 0
    while chunk := source.read(CHUNK):
        _write(digest, out, chunk)
        size += len(chunk)
    return size


def _settle(temp: Path, final: Path) -> None:
    if final.exists():  # the same content is already there: keep it, as new
        temp.unlink()
        os.utime(final)  # remove_unused spares a recent file (its job may not be stored yet)
    else:
        temp.replace(final)


def _flush(out: IO[bytes]) -> None:
    # On disk before the rename: a power cut must not leave a named but empty file.
    out.flush()
    os.fsync(out.fileno())


async def _parser(timeout: float) -> Path:
    """Moonraker's metadata.py in the Moonraker runtime, found once per process."""
    python = MOONRAKER.python
    if python not in _parsers:
        if not python.exists():
            raise FileNotFoundError(
                f"the Moonraker runtime is not installed ({python}); `kybercore demo` installs it "
                "once"
            )
        out = await _run([str(python), "-c", _FIND_PARSER], timeout)
        script = Path(out.decode().strip()) / "components" / "file_manager" / "metadata.py"
        if not script.is_file():
            raise FileNotFoundError(f"Moonraker's metadata parser is not at {script}")
        _parsers[python] = script
    return _parsers[python]


async def _run(command: list[str], timeout: float) -> bytes:
    """``command``'s standard output; an exit status other than 0 or a timeout raises."""
    process = await asyncio.create_subprocess_exec(
        *command, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
    )
    try:
        out, err = await asyncio.wait_for(process.communicate(), timeout)
    except BaseException:  # timed out or cancelled: the process must not outlive the call
        with contextlib.suppress(ProcessLookupError):
            process.kill()
        await process.wait()
        raise
    if process.returncode != 0:
        tail = err.decode(errors="replace").strip().splitlines()[-1:] or ["no message"]
        raise ValueError(f"{Path(command[1]).name} exited with {process.returncode}: {tail[0]}")
    return out
