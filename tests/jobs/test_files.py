"""The queue's file store: content-addressed files, streamed in, described by Moonraker's own
metadata parser (the real one, from the Moonraker runtime), never half-written."""

from __future__ import annotations

import asyncio
import hashlib
import io
import logging
import os
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from kybercore.core.validation import PrinterFacts, validate
from kybercore.errors import FileNotFound, InvalidInput
from kybercore.jobs import files as files_module
from kybercore.jobs.files import GRACE, JobFiles
from kybercore.sim.runtime import Runtime

SAMPLES = Path(files_module.__file__).parents[1] / "sim" / "samples"
PLA_CUBE = (SAMPLES / "calibration_cube_20mm_pla.gcode").read_bytes()
PETG_TOWER = (SAMPLES / "tower_60mm_petg.gcode").read_bytes()

pytestmark = pytest.mark.usefixtures("runtimes")


@pytest.fixture
def store(tmp_path: Path) -> JobFiles:
    return JobFiles(tmp_path / "files")


def listing(folder: Path) -> list[str]:
    """Every file under ``folder``, hidden ones included."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


async def chunks(data: bytes, size: int = 1000) -> AsyncIterator[bytes]:
    for i in range(0, len(data), size):
        await asyncio.sleep(0)
        yield data[i : i + size]


async def test_a_file_is_stored_under_its_sha256_with_moonrakers_metadata(store: JobFiles) -> None:
    stored = await store.put("cube.gcode", PLA_CUBE)
    assert stored.sha256 == hashlib.sha256(PLA_CUBE).hexdigest()
    assert (stored.name, stored.size) == ("cube.gcode", len(PLA_CUBE))
    assert store.path(stored.sha256).read_bytes() == PLA_CUBE
    meta = stored.meta
    assert meta["slicer"] == "PrusaSlicer"
    assert meta["filament_type"] == "PLA"
    assert meta["nozzle_diameter"] == 0.4
    assert meta["object_height"] == 30.0
    assert meta["estimated_time"] == 136
    assert (meta["first_layer_extr_temp"], meta["first_layer_bed_temp"]) == (205.0, 60.0)
    assert meta["size"] == len(PLA_CUBE)
    # What describes this copy on disk, not the content, is left out.
    assert "uuid" not in meta
    assert "modified" not in meta
    thumbs = {t["relative_path"] for t in meta["thumbnails"]}
    assert thumbs == {f".thumbs/{stored.sha256}-32x32.png", f".thumbs/{stored.sha256}-48x48.png"}
    assert all((store.folder / t).is_file() for t in thumbs)


async def test_the_same_content_twice_is_one_file_however_it_comes(store: JobFiles) -> None:
    first = await store.put("a.gcode", PLA_CUBE)
    second = await store.put("b.gcode", chunks(PLA_CUBE))
    third = await store.put("c.gcode", io.BytesIO(PLA_CUBE))
    assert first.sha256 == second.sha256 == third.sha256
    assert first.meta == second.meta == third.meta
    assert [f.name for f in (first, second, third)] == ["a.gcode", "b.gcode", "c.gcode"]
    both = await asyncio.gather(store.put("d.gcode", PETG_TOWER), store.put("e.gcode", PETG_TOWER))
    assert both[0].sha256 == both[1].sha256
    gcode = [name for name in listing(store.folder) if not name.startswith(".thumbs/")]
    assert gcode == sorted(f"{sha}.gcode" for sha in (first.sha256, both[0].sha256))


async def test_a_half_written_upload_leaves_nothing_behind(store: JobFiles) -> None:
    async def broken() -> AsyncIterator[bytes]:
        yield PLA_CUBE[:4000]
        raise ConnectionResetError("the client went away")

    with pytest.raises(ConnectionResetError):
        await store.put("cube.gcode", broken())
    assert listing(store.folder) == []


async def test_a_cancelled_upload_leaves_nothing_behind(store: JobFiles) -> None:
    started = asyncio.Event()

    async def stalled() -> AsyncIterator[bytes]:
        yield PLA_CUBE[:4000]
        started.set()
        await asyncio.Event().wait()  # the rest never comes
        yield b""

    put = asyncio.create_task(store.put("cube.gcode", stalled()))
    await started.wait()
    assert [n for n in listing(store.folder) if n.endswith(".part")]  # it was being written
    put.cancel()
    with pytest.raises(asyncio.CancelledError):
        await put
    assert listing(store.folder) == []


async def test_a_file_the_parser_finds_nothing_in_is_stored_without_slicer_data(
    store: JobFiles,
) -> None:
    stored = await store.put("notes.gcode", b"; just a comment\nG28\n")
    assert stored.meta["slicer"] == "Unknown"
    assert "filament_type" not in stored.meta


async def test_a_parser_that_hangs_gives_empty_metadata_and_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # No Python starts, let alone parses, within a millisecond.
    store = JobFiles(tmp_path / "files", parse_timeout=0.001)
    with caplog.at_level(logging.WARNING, logger="kybercore.jobs.files"):
        stored = await store.put("cube.gcode", PLA_CUBE)
    assert stored.meta == {}
    assert store.path(stored.sha256).read_bytes() == PLA_CUBE
    assert f"No metadata for job file {stored.sha256}" in caplog.text


async def test_a_missing_parser_or_file_gives_empty_metadata_and_a_warning(
    store: JobFiles,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    stored = await store.put("cube.gcode", PLA_CUBE)
    store.path(stored.sha256).unlink()
    with caplog.at_level(logging.WARNING, logger="kybercore.jobs.files"):
        assert await store.metadata(stored.sha256) == {}
        assert "exited with" in caplog.text
        monkeypatch.setattr(files_module, "MOONRAKER", Runtime("nowhere", "moonraker==0"))
        monkeypatch.setenv("KYBERCORE_HOME", str(tmp_path / "empty-home"))
        assert (await store.put("cube.gcode", PLA_CUBE)).meta == {}
    assert "the Moonraker runtime is not installed" in caplog.text


async def test_a_stored_file_opens_and_a_missing_one_says_so(store: JobFiles) -> None:
    stored = await store.put("cube.gcode", PLA_CUBE)
    handle = await store.open(stored.sha256)
    with handle:
        assert handle.read() == PLA_CUBE
    with pytest.raises(FileNotFound):
        await store.open("0" * 64)
    for bad in ("../printers.json", "A" * 64, "0" * 63):
        with pytest.raises(InvalidInput):
            store.path(bad)


async def test_unused_files_go_once_they_are_old(store: JobFiles) -> None:
    kept = await store.put("cube.gcode", PLA_CUBE)
    unused = await store.put("tower.gcode", PETG_TOWER)
    recent = await store.put("notes.gcode", b"G28\n")
    crash_debris = store.folder / ".upload-crash.part"
    crash_debris.write_bytes(b"half")
    fresh_temp = store.folder / ".upload-now.part"
    fresh_temp.write_bytes(b"being written by another process")
    past = time.time() - GRACE - 10
    for path in (store.path(kept.sha256), store.path(unused.sha256), crash_debris):
        os.utime(path, (past, past))
    assert await store.remove_unused({kept.sha256}) == [unused.sha256]
    left = listing(store.folder)
    assert not [name for name in left if unused.sha256 in name]  # its thumbnails too
    assert f"{kept.sha256}.gcode" in left
    assert f".thumbs/{kept.sha256}-32x32.png" in left
    assert f"{recent.sha256}.gcode" in left  # its job may not be stored yet
    assert ".upload-now.part" in left
    assert ".upload-crash.part" not in left
    # Putting old content again makes it recent: a job about to be stored keeps its file.
    os.utime(store.path(kept.sha256), (past, past))
    await store.put("again.gcode", PLA_CUBE)
    assert await store.remove_unused(set()) == []


async def test_the_rules_read_the_metadata_as_validation_expects(store: JobFiles) -> None:
    pla_printer = PrinterFacts(
        connection="online", klippy_state="ready", print_state="standby",
        build_volume=(250.0, 250.0, 50.0), nozzle_diameter=0.4, material="PLA",
        max_extruder_temp=300.0, max_bed_temp=120.0,
    )  # fmt: skip
    found = {}
    for sample in sorted(SAMPLES.glob("*.gcode")):
        stored = await store.put(sample.name, sample.read_bytes())
        verdict = validate("start", pla_printer, params={"filename": sample.name},
                           file_meta=stored.meta)  # fmt: skip
        found[sample.name] = sorted(r.code for r in verdict.reasons)
    assert found == {
        "calibration_cube_10mm_petg.gcode": ["filament_mismatch"],
        "calibration_cube_20mm_pla.gcode": [],
        "tower_60mm_petg.gcode": ["filament_mismatch", "file_too_tall"],
    }
