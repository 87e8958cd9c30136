"""What `kybercore demo` queues: sample files that exist and need what they say, and a
queue that starts afresh with each demo."""

from __future__ import annotations

from pathlib import Path

from kybercore.cli.serve import _default_database, _forget_demo_queue
from kybercore.sim.demo import DEMO_JOBS, MODELS, sample_files


def test_the_demo_jobs_are_samples_sliced_for_the_material_they_ask_for() -> None:
    samples = dict(sample_files())
    loaded = {model.material for model in MODELS[:3]}  # the default demo: 3 printers
    for job in DEMO_JOBS:
        header = samples[job.file].decode()
        assert f"; filament_type = {job.material}" in header, job
        assert job.material in loaded, job
    # One job waits for a busy printer: more PETG jobs than PETG printers.
    petg = [job for job in DEMO_JOBS if job.material == "PETG"]
    assert len(petg) > sum(model.material == "PETG" for model in MODELS[:3])


def test_each_demo_forgets_the_last_runs_queue(tmp_path: Path) -> None:
    printers = tmp_path / "printers.json"
    database = Path(_default_database(printers).split(":///", 1)[1])
    printers.write_text("{}")
    for path in (database, database.with_name(database.name + "-wal"), tmp_path / "files" / "x"):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"old")
    _forget_demo_queue(printers)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["printers.json"]
