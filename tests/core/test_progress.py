"""Progress and time left: from the file position within the G-code, never backwards during a
print, unknown ("—") until extrusion starts.

The two reported cases replay real sample files with the metadata Moonraker's own parser
gives them; the property test throws any sequence of Moonraker updates of a print at the view.
"""

from __future__ import annotations

import re
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kybercore.core.progress import PrintMemory, estimate, file_progress, track
from kybercore.core.view import LivePrinter, View, fuse, tracked
from kybercore.jobs.files import JobFiles
from kybercore.registry.models import PrinterConfig

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "src/kybercore/sim/samples/tower_60mm_petg.gcode"
ORCA_CUBE = ROOT / "tests/samples/gcode/orcaslicer_cube_20mm_pla.gcode"
CONFIG = PrinterConfig(id="p1", name="Printer 1", moonraker_url="http://127.0.0.1:7125")
T0 = 1_800_000_000.0
"""Unix time at which the replayed prints start."""


@pytest.fixture(scope="module")
async def metadata(runtimes: None) -> dict[str, dict[str, Any]]:
    """The sample files' metadata as Moonraker's parser reads it."""
    with tempfile.TemporaryDirectory() as folder:
        files = JobFiles(Path(folder))
        return {
            p.name: dict((await files.put(p.name, p.read_bytes())).meta) for p in (TOWER, ORCA_CUBE)
        }


@dataclass
class Printer:
    """One printer's live state as the fleet keeps it, rendered as the fleet publishes it."""

    live: LivePrinter = field(
        default_factory=lambda: LivePrinter(connection="online", klippy_state="ready")
    )

    def update(self, status: dict[str, Any], meta: dict[str, Any] | None, now: float) -> View:
        self.live.status = status
        self.live.file_meta = meta
        self.live.updated_at = now
        self.live.print_memory = tracked(self.live)  # what Sessions.render does
        return fuse(CONFIG, self.live)


@dataclass
class Sample:
    """Klippy's state while it runs one line of the file."""

    position: int
    duration: float
    filament: float
    m73: float
    heating: bool


def replay(path: Path, seconds_per_move: float) -> Iterator[Sample]:
    """The file run line by line as virtual_sdcard does: ``file_position`` is the start of
    the line running; ``print_duration`` counts from the first extrusion; M73 sets the
    display progress."""
    position = duration = filament = m73 = 0.0
    extruded = False
    for raw in path.read_bytes().splitlines(keepends=True):
        line = raw.decode().split(";")[0].strip()
        yield Sample(int(position), duration, filament, m73, line[:4] in ("M190", "M109"))
        position += len(raw)
        if match := re.fullmatch(r"M73 P(\d+).*", line):
            m73 = int(match[1]) / 100
        if line.startswith("G1"):
            extrusion = re.search(r"E(-?[\d.]+)", line)
            amount = float(extrusion[1]) if extrusion else 0.0
            extruded = extruded or amount > 0
            filament += max(amount, 0.0)
            if extruded:
                duration += seconds_per_move


def status_of(
    sample: Sample, size: int, state: str = "printing", name: str = "x"
) -> dict[str, Any]:
    return {
        "print_stats": {
            "state": state,
            "filename": name,
            "print_duration": sample.duration,
            "total_duration": sample.duration + 30,
            "filament_used": sample.filament,
        },
        "virtual_sdcard": {
            "file_position": sample.position,
            "file_size": size,
            "progress": sample.position / size,
            "is_active": True,
        },
        "display_status": {"progress": sample.m73},
    }


def test_a_tower_print_follows_the_file_not_the_m73_steps(
    metadata: dict[str, dict[str, Any]],
) -> None:
    """printer-2 printing tower_60mm_petg: progress stuck at the M73 steps while the time
    left climbed 279 -> 381 s, and the tile went from 11 % back to 10 %."""
    meta = {**metadata[TOWER.name], "filename": "tower.gcode"}
    start, end, size = meta["gcode_start_byte"], meta["gcode_end_byte"], meta["size"]
    moves = sum(1 for line in TOWER.read_text().splitlines() if line.startswith("G1"))
    printer = Printer()
    views = []
    for sample in replay(TOWER, meta["estimated_time"] / moves):
        now = T0 + 60 + sample.duration  # a minute of heating first
        view = printer.update(status_of(sample, size, name="tower.gcode"), meta, now)
        views.append((sample, view["job"]))
    progress = [job["progress"] for _, job in views]
    assert progress == sorted(progress), "progress went backwards"
    for sample, job in views:
        assert job["progress"] == pytest.approx(
            min(max((sample.position - start) / (end - start), 0), 1), abs=1e-4
        )
    # Between two M73 steps the progress moves on with the file.
    between = [job["progress"] for s, job in views if s.m73 == 0.1]
    assert between[-1] - between[0] > 0.08
    printing = [(s, job) for s, job in views if s.duration > 0 and s.position < end]
    assert len(printing) > 500
    lowest = printing[0][1]["eta_seconds"]
    for _, job in printing:
        # Lines are not all as long nor as slow: a few seconds of noise, never a climb.
        assert job["eta_seconds"] <= lowest + 5, "time left went up"
        lowest = min(lowest, job["eta_seconds"])
    # A steady pace gives a steady finish time ("done at" does not wander).
    finish = [job["eta_at"] for _, job in printing]
    assert max(finish) - min(finish) < 0.05 * meta["estimated_time"]


def test_an_orca_cube_heating_has_no_time_left_and_no_header_progress(
    metadata: dict[str, dict[str, Any]],
) -> None:
    """printer-3 starting orcaslicer_cube: "21 % · 0 s left" with the hotend at 124/220 °C
    (21 % is the thumbnail header's share of the file)."""
    meta = {**metadata[ORCA_CUBE.name], "filename": "cube.gcode"}
    printer = Printer()
    samples = list(replay(ORCA_CUBE, 1.0))
    heating = next(s for s in samples if s.heating)
    status = status_of(heating, meta["size"], name="cube.gcode")
    assert status["virtual_sdcard"]["progress"] > 0.2  # what the tile showed
    job = printer.update(status, meta, T0)["job"]
    assert job["progress"] < 0.05
    assert (job["eta_seconds"], job["eta_at"]) == (None, None)

    extruding = next(s for s in samples if s.duration > 0)
    job = printer.update(status_of(extruding, meta["size"], name="cube.gcode"), meta, T0 + 40)[
        "job"
    ]
    assert job["eta_seconds"] > 0
    assert abs(job["eta_at"] - (T0 + 40 + job["eta_seconds"])) <= 1


def _status(state: str, position: int, duration: float, name: str = "a.gcode") -> dict[str, Any]:
    return status_of(Sample(position, duration, 0.0, 0.0, False), 2000, state, name)


META = {"filename": "a.gcode", "gcode_start_byte": 100, "gcode_end_byte": 1100, "size": 2000}


def test_a_new_print_of_the_same_file_starts_from_zero() -> None:
    memory = track(PrintMemory(), _status("printing", 900, 50), META)
    memory = track(memory, _status("complete", 1100, 60), META)
    assert memory.progress == 1.0
    memory = track(memory, _status("printing", 150, 0), META)
    assert memory.progress == pytest.approx(0.05)


def test_a_cancelled_print_keeps_the_progress_it_reached() -> None:
    memory = track(PrintMemory(), _status("printing", 600, 50), META)
    cancelled = _status("cancelled", 0, 50)  # CANCEL_PRINT reset the file position
    assert estimate(memory, cancelled, META, T0).progress == pytest.approx(0.5)
    assert estimate(memory, cancelled, META, T0).eta_seconds is None


def test_a_new_print_is_seen_from_its_duration_when_the_states_between_were_missed() -> None:
    memory = track(PrintMemory(), _status("printing", 1000, 500), META)
    memory = track(memory, _status("printing", 300, 5), META)
    assert memory.progress == pytest.approx(0.2)


def test_while_the_metadata_is_read_the_progress_waits() -> None:
    pending = {"filename": "a.gcode"}
    assert file_progress(_status("printing", 400, 0), pending) is None
    memory = track(PrintMemory(), _status("printing", 400, 0), pending)
    assert memory.progress == 0
    assert estimate(memory, _status("printing", 420, 3), pending, T0).eta_seconds is None
    assert track(memory, _status("printing", 420, 3), META).progress == pytest.approx(0.32)


def test_without_a_byte_range_the_progress_is_the_virtual_sdcard_s_then_m73() -> None:
    unavailable = {"filename": "a.gcode", "unavailable": True}
    assert file_progress(_status("printing", 500, 1), unavailable) == pytest.approx(0.25)
    host_stream = {"print_stats": {"state": "printing"}, "display_status": {"progress": 0.4}}
    assert file_progress(host_stream, unavailable) == pytest.approx(0.4)


def test_time_left_blends_the_file_filament_and_slicer_estimates() -> None:
    meta = {**META, "estimated_time": 1000, "filament_total": 1000}
    heating = track(PrintMemory(), _status("printing", 100, 0), meta)
    status = _status("printing", 600, 300)  # half of the G-code in 300 s
    status["print_stats"]["filament_used"] = 250.0  # a quarter of the filament
    left = estimate(heating, status, meta, T0)
    by_file, by_filament = 300.0, 900.0
    assert left.eta_seconds == pytest.approx((by_file + by_filament) / 2)
    assert left.eta_at == pytest.approx(T0 + 600)
    # Early on, the slicer's estimate of what is left weighs in.
    early = _status("printing", 150, 20)
    assert estimate(heating, early, meta, T0).eta_seconds == pytest.approx(
        1000 * 0.95 * 0.75 + (20 / 0.05 * 0.95) * 0.25
    )
    # At the end of the G-code nothing is left; not printing, nothing is estimated.
    assert estimate(heating, _status("printing", 1100, 900), meta, T0).eta_seconds == 0
    assert estimate(heating, _status("complete", 1100, 900), meta, T0).eta_seconds is None


def test_the_start_g_code_s_share_does_not_count_as_printed() -> None:
    """Heating seen: the pace counts from where extrusion began, not from the first byte."""
    heating = track(PrintMemory(), _status("printing", 300, 0), META)  # 20 % is start G-code
    extruding = track(heating, _status("printing", 310, 1), META)
    assert extruding.extruding_from == pytest.approx(0.2)
    left = estimate(extruding, _status("printing", 610, 60), META, T0)
    assert left.eta_seconds == pytest.approx(60 / 0.31 * 0.49)
    # Joined in the middle of a print: the start G-code's share is unknown, taken as 0.
    joined = track(PrintMemory(), _status("printing", 610, 60), META)
    assert estimate(joined, _status("printing", 610, 60), META, T0).eta_seconds == pytest.approx(
        60 / 0.51 * 0.49
    )


# -- the property: any sequence of updates during a print ------------------------------------


@st.composite
def prints(draw: st.DrawFn) -> tuple[dict[str, Any], list[dict[str, Any]], int]:
    """A file's metadata, the Moonraker updates of one print of it (heating first), and the
    update at which the metadata has been read."""
    start = draw(st.integers(0, 5000))
    end = start + draw(st.integers(1, 1_000_000))
    size = end + draw(st.integers(0, 5000))
    meta: dict[str, Any] = {
        "filename": "f.gcode",
        "size": size,
        "gcode_start_byte": start,
        "gcode_end_byte": end,
    }
    if draw(st.booleans()):
        meta["estimated_time"] = draw(st.integers(1, 100_000))
    if draw(st.booleans()):
        meta["filament_total"] = draw(st.floats(1, 100_000))
    position, duration, filament = draw(st.integers(0, start + 10)), 0.0, 0.0
    updates = []
    for _ in range(draw(st.integers(1, 6))):  # heating: no extrusion yet
        position = min(size, position + draw(st.integers(0, 200)))
        updates.append(_update("printing", position, 0.0, 0.0, draw(st.floats(0, 1)), size))
    for _ in range(draw(st.integers(0, 40))):
        position = min(size, position + draw(st.integers(0, max(1, (end - start) // 10))))
        duration += draw(st.floats(0.01, 600))
        filament += draw(st.floats(0, 500))
        state = draw(st.sampled_from(["printing", "printing", "paused"]))
        updates.append(_update(state, position, duration, filament, draw(st.floats(0, 1)), size))
    if draw(st.booleans()):
        final = draw(st.sampled_from(["complete", "cancelled", "error"]))
        updates.append(
            _update(final, draw(st.sampled_from([0, position])), duration, filament, 0, size)
        )
    return meta, updates, draw(st.integers(0, len(updates)))


def _update(
    state: str, position: int, duration: float, filament: float, m73: float, size: int
) -> dict[str, Any]:
    sample = Sample(position, duration, filament, m73, False)
    return status_of(sample, size, state, "f.gcode")


@given(prints())
def test_progress_never_decreases_and_time_left_waits_for_extrusion(
    case: tuple[dict[str, Any], list[dict[str, Any]], int],
) -> None:
    meta, updates, meta_read_at = case
    printer = Printer()
    shown = 0.0
    for i, status in enumerate(updates):
        now = T0 + i
        job = printer.update(status, meta if i >= meta_read_at else {"filename": "f.gcode"}, now)[
            "job"
        ]
        assert 0 <= job["progress"] <= 1
        assert job["progress"] >= shown, "progress went backwards"
        shown = job["progress"]
        stats = status["print_stats"]
        extruding = stats["print_duration"] > 0 and (
            status["virtual_sdcard"]["file_position"] >= meta["gcode_start_byte"]
        )
        if not extruding or stats["state"] not in ("printing", "paused"):
            assert (job["eta_seconds"], job["eta_at"]) == (None, None)
            continue
        if i >= meta_read_at and meta.get("estimated_time"):
            assert job["eta_seconds"] is not None, "the slicer's estimate was there"
        if job["eta_seconds"] is not None:
            assert job["eta_seconds"] >= 0
            assert abs(job["eta_at"] - (now + job["eta_seconds"])) <= 1
