"""Files replaced whole: a crash at any point leaves the old version or the new one, never
part of either. Blocking: async code calls these through ``asyncio.to_thread``."""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

log = logging.getLogger(__name__)


def replace_file(
    path: Path, data: bytes, *, before_replace: Callable[[], None] | None = None
) -> None:
    """Write ``data`` to a temp file beside ``path`` (created 0600: some of these files hold
    secrets), fsync it, run ``before_replace`` (printers.json keeps its backup then), rename
    it over ``path`` and fsync the folder. A failure before the rename leaves ``path`` as it
    was and no temp file; once the new file is in place, a failed fsync of the folder is
    logged as a warning, not raised (the file did change)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        if before_replace is not None:
            before_replace()
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:
        _fsync_dir(path.parent)
    except OSError as exc:
        # Saying "not changed" would be false. Only whether it survives a power cut in the
        # next seconds is in doubt.
        log.warning(
            "%s: written, but its folder could not be synced (%s); a power cut in the next "
            "seconds could bring back the previous version.",
            path, exc,
        )  # fmt: skip


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
