"""Files replaced whole (:mod:`kybercore.files`): a write that fails leaves the old file as
it was and no temp file beside it; one that succeeds leaves the new file, readable only by
its owner (printers.json and the token file hold secrets)."""

from __future__ import annotations

from pathlib import Path

import pytest

from kybercore.files import replace_file


def test_a_write_replaces_the_file_whole_and_only_its_owner_reads_it(tmp_path: Path) -> None:
    path = tmp_path / "folder" / "state.json"
    replace_file(path, b"old")
    replace_file(path, b"new")
    assert path.read_bytes() == b"new"
    assert path.stat().st_mode & 0o777 == 0o600
    assert [p.name for p in path.parent.iterdir()] == ["state.json"]


def test_a_write_that_fails_before_the_replace_leaves_the_old_file(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    replace_file(path, b"old")

    def disk_full() -> None:
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space left"):
        replace_file(path, b"new", before_replace=disk_full)
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["state.json"]
