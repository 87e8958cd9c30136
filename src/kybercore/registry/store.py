"""printers.json: read, validate, write atomically, and notice edits made on disk.

The format lives in :mod:`kybercore.registry.format`, the models in
:mod:`kybercore.registry.models`; this module does the I/O.

- A file that does not parse or validate raises :class:`ConfigError` naming the file, line,
  column and reason, and is never overwritten.
- Writes go to a temp file in the same folder (fsync), the old file is kept as
  ``printers.json.bak``, then ``os.replace`` and an fsync of the folder: a crash at any point
  leaves either the old or the new file, whole.
- Every mutation is read-modify-write under a ``threading.Lock`` and a cross-process
  ``filelock`` on ``printers.json.lock``, so the server and the CLI writing at once lose nothing.
- Reading the last good fleet (:attr:`PrinterRegistry.printers`) takes no lock: the event
  loop reads it while a writer may wait up to ``LOCK_TIMEOUT`` for another process.

All methods are blocking; async code calls them through ``asyncio.to_thread``, except
:meth:`PrinterRegistry.watch`, which is a coroutine.
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import os
import shutil
import threading
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Final

import filelock

from kybercore.errors import ConfigError, UnknownPrinter
from kybercore.files import replace_file
from kybercore.registry import changes
from kybercore.registry.format import backup_path, dump_printers, parse_printers
from kybercore.registry.models import PrinterConfig, PrinterCreate, PrinterUpdate

log = logging.getLogger(__name__)

LOCK_TIMEOUT: Final = 10.0
"""Seconds to wait for another process's write before giving up."""

Signature = tuple[int, int, int] | None
"""(mtime_ns, size, inode) of the file, None when it does not exist."""

OnChange = Callable[[list[PrinterConfig]], Awaitable[None] | None]
OnError = Callable[[ConfigError], Awaitable[None] | None]


def default_printers_path() -> Path:
    """``$KYBERCORE_PRINTERS`` if set, else ``printers.json`` in the working directory."""
    return Path(os.environ.get("KYBERCORE_PRINTERS") or "printers.json")


def read_printers(path: Path) -> list[PrinterConfig]:
    """The printers stored in ``path``; an empty fleet if it does not exist.

    Raises :class:`ConfigError` (file, line, column, reason, what to do) if it is unusable.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return []
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(
            f"{path}: cannot be read ({exc}). Check the file and its permissions."
        ) from None
    return parse_printers(text, path)


def write_printers(path: Path, printers: list[PrinterConfig]) -> None:
    """Replace ``path`` atomically with ``printers``, keeping the old file as ``.bak``.

    Does not lock: callers hold the registry's locks. On a failure before the replace the
    old file is intact and the temp file is removed; once the new file is in place, a
    failed fsync of the folder is logged as a warning, not raised (the file did change).
    """
    data = dump_printers(printers)  # API keys: replace_file creates the file 0600

    def keep_backup() -> None:
        if path.exists():
            _backup(path)

    replace_file(path, data, before_replace=keep_backup)


def _backup(path: Path) -> None:
    """Make ``path.bak`` the current ``path``, atomically (a hardlink needs no data copy)."""
    bak_tmp = path.with_name(f".{path.name}.bak.tmp")
    bak_tmp.unlink(missing_ok=True)
    try:
        os.link(path, bak_tmp)
    except OSError:  # a filesystem without hardlinks
        shutil.copy2(path, bak_tmp)
    os.replace(bak_tmp, backup_path(path))


def file_signature(path: Path) -> Signature:
    """What tells one version of a file from another without reading it: (mtime_ns, size,
    inode). The inode and size catch a replace within one tick of a coarse clock."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return (st.st_mtime_ns, st.st_size, st.st_ino)


class PrinterRegistry:
    """The fleet's printers.json, with the last good configuration kept in memory.

    :meth:`reload` reads the file; :attr:`printers` is the last list that
    validated. Mutations re-read the file under the locks, so they never lose another
    process's write, and refuse to touch a file that does not validate.
    """

    def __init__(self, path: Path | str | None = None) -> None:
        self.path = Path(path) if path is not None else default_printers_path()
        self.last_error: str | None = None
        """Why the last reload failed; None once the file is good again."""
        self._printers: tuple[PrinterConfig, ...] = ()
        """Replaced whole, never changed in place: readers need no lock."""
        self._seen: Signature = None
        self._lock = threading.Lock()
        self._file_lock = filelock.FileLock(
            self.path.with_name(self.path.name + ".lock"), timeout=LOCK_TIMEOUT
        )

    @property
    def printers(self) -> list[PrinterConfig]:
        """The last good configuration (a copy). Never waits: safe on the event loop."""
        return list(self._printers)

    def get(self, printer_id: str) -> PrinterConfig:
        """The printer ``printer_id`` from the last good configuration, or UnknownPrinter."""
        for printer in self.printers:
            if printer.id == printer_id:
                return printer
        raise UnknownPrinter(printer_id)

    def changed(self) -> bool:
        """Whether the file changed on disk since it was last read or written (one stat)."""
        with self._lock:
            return file_signature(self.path) != self._seen

    def reload(self) -> list[PrinterConfig]:
        """Read the file (at start-up, or again after :meth:`changed`) and return the list.

        On ConfigError the last good configuration stays in :attr:`printers` and the reason
        in :attr:`last_error`; the same broken file is not reported again by :meth:`changed`.
        """
        with self._lock:
            # Stat before reading: an edit landing during the read shows up on the next check.
            self._seen = file_signature(self.path)
            try:
                printers = read_printers(self.path)
            except ConfigError as exc:
                self.last_error = exc.message
                raise
            self._printers = tuple(printers)
            self.last_error = None
            return printers

    def add(self, new: PrinterCreate) -> PrinterConfig:
        """Add a printer and return it as stored (rules: :func:`changes.add_printer`)."""
        return self._mutate(lambda printers: changes.add_printer(printers, new))

    def update(self, printer_id: str, patch: PrinterUpdate) -> PrinterConfig:
        """Apply ``patch`` to printer ``printer_id`` and return it as stored (rules:
        :func:`changes.update_printer`)."""
        return self._mutate(lambda printers: changes.update_printer(printers, printer_id, patch))

    def remove(self, printer_id: str) -> PrinterConfig:
        """Remove printer ``printer_id`` and return what it was."""
        return self._mutate(lambda printers: changes.remove_printer(printers, printer_id))

    def _mutate(self, change: Callable[[list[PrinterConfig]], PrinterConfig]) -> PrinterConfig:
        """Read-modify-write under both locks; the in-memory list follows the file."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self._locked():
                before = file_signature(self.path)
                printers = read_printers(self.path)
                result = change(printers)
                _remove_stale_temp_files(self.path)
                write_printers(self.path, printers)
                self._printers = tuple(printers)
                self.last_error = None
                # If someone else edited the file since we last looked, leave _seen stale so
                # watch() still reports the merged result; otherwise this write is ours alone.
                if before == self._seen:
                    self._seen = file_signature(self.path)
                return result
        except OSError as exc:
            raise ConfigError(
                f"{self.path}: cannot be written ({exc}). Check that its folder exists and "
                "is writable; the file was not changed."
            ) from exc

    @contextmanager
    def _locked(self) -> Iterator[None]:
        """Both locks: threads of this process, then other processes."""
        with self._lock:
            try:
                self._file_lock.acquire()
            except filelock.Timeout:
                raise ConfigError(
                    f"{self.path}: another process has held {self._file_lock.lock_file} for "
                    f"{LOCK_TIMEOUT:.0f} s. Retry; if it persists, look for a stuck kybercore."
                ) from None
            try:
                yield
            finally:
                self._file_lock.release()

    async def watch(self, on_change: OnChange, on_error: OnError, interval: float = 1.0) -> None:
        """Poll the file forever: ``on_change(printers)`` after a good edit on disk,
        ``on_error(ConfigError)`` after a broken one (the last good list is kept).

        Writes made through this registry are not reported unless they merged someone
        else's edit; the caller acts on their return value. Callbacks may be sync or async.
        Run it as a task and cancel it to stop.
        """
        while True:
            await asyncio.sleep(interval)
            if not await asyncio.to_thread(self.changed):
                continue
            try:
                printers = await asyncio.to_thread(self.reload)
            except ConfigError as exc:
                log.warning("printers.json edit rejected: %s", exc.message)
                await _call(on_error, exc)
            else:
                log.info("printers.json changed on disk: %d printers", len(printers))
                await _call(on_change, printers)


async def _call(callback: Callable[[Any], Awaitable[None] | None], arg: Any) -> None:
    result = callback(arg)
    if inspect.isawaitable(result):
        await result


def _remove_stale_temp_files(path: Path) -> None:
    # Left by a writer killed mid-write; safe to delete because we hold the file lock.
    for stale in path.parent.glob(f".{path.name}.*.tmp"):
        stale.unlink(missing_ok=True)
