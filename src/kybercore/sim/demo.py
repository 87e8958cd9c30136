"""A demo fleet: heterogeneous virtual printers, their printers.json, sample files and
the jobs the demo queues.

Used by ``kybercore demo`` (printers + dashboard + a queue) and ``kybercore sim`` (printers
only).
One demo per data folder: a file lock keeps a second one from starting beside it, and
the PIDs of a demo that died without cleaning up are stopped before a new one starts.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Final

import filelock

from kybercore.errors import InvalidInput, LaunchError
from kybercore.registry.models import Capabilities, PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.sim.stack import PrinterStack, StackOptions, ensure_port_free


@dataclass(frozen=True)
class DemoModel:
    """One kind of printer in the demo fleet."""

    model: str
    size: tuple[float, float, float]
    nozzle: float
    hotend_max: float
    bed_max: float
    material: str
    room: str


# A farm is rarely uniform: different sizes, nozzles, heater limits and materials.
MODELS: Final = (
    DemoModel("Voron 2.4 350", (350.0, 350.0, 330.0), 0.4, 300.0, 120.0, "PLA", "Room A"),
    DemoModel("Prusa MK4", (250.0, 210.0, 220.0), 0.4, 290.0, 120.0, "PETG", "Room A"),
    DemoModel("Ender 3 V2", (220.0, 220.0, 250.0), 0.4, 260.0, 100.0, "PLA", "Room B"),
    DemoModel("CoreXY 256", (256.0, 256.0, 256.0), 0.6, 300.0, 110.0, "PETG", "Room B"),
    DemoModel("RatRig V-Core 3", (300.0, 300.0, 300.0), 0.4, 300.0, 120.0, "PLA", "Room C"),
)


def _model(index: int) -> DemoModel:
    return MODELS[index % len(MODELS)]


def fleet_options(
    count: int, base_port: int = 0, heat_rate: float | None = None
) -> list[StackOptions]:
    """Options for ``count`` varied printers; ports from ``base_port`` (0 = any free)."""
    return [
        StackOptions(
            name=f"printer-{index + 1}",
            port=base_port + index if base_port else 0,
            size=_model(index).size,
            nozzle_diameter=_model(index).nozzle,
            extruder_max_temp=_model(index).hotend_max,
            bed_max_temp=_model(index).bed_max,
            heat_rate=heat_rate,
        )
        for index in range(count)
    ]


def fleet_printers(stacks: list[PrinterStack]) -> list[PrinterConfig]:
    """printers.json entries pointing at running stacks."""
    return [
        PrinterConfig(
            id=stack.options.name,
            name=f"{_model(index).model} #{index + 1}",
            model=_model(index).model,
            location=_model(index).room,
            tags=["demo", _model(index).material.lower()],
            moonraker_url=stack.url,
            capabilities=Capabilities(material=_model(index).material),
        )
        for index, stack in enumerate(stacks)
    ]


def sample_files() -> list[tuple[str, bytes]]:
    """The sample G-code files shipped with KyberCore (name, content)."""
    folder = resources.files("kybercore.sim") / "samples"
    return sorted(
        (entry.name, entry.read_bytes())
        for entry in folder.iterdir()
        if entry.name.endswith(".gcode")
    )


@dataclass(frozen=True)
class DemoJob:
    """A job ``kybercore demo`` queues: a sample file, its copies, the material it needs."""

    file: str
    copies: int
    material: str


DEMO_JOBS: Final = (
    # Runs on the PLA printers, one copy each, the next one after each plate clear.
    DemoJob("calibration_cube_20mm_pla.gcode", 4, "PLA"),
    # Takes the PETG printer...
    DemoJob("calibration_cube_10mm_petg.gcode", 2, "PETG"),
    # ...so this one waits, and says why: PLA loaded elsewhere, the PETG printer busy.
    DemoJob("tower_60mm_petg.gcode", 1, "PETG"),
)


def copy_samples(stack: PrinterStack) -> None:
    """Put the sample files on a printer's virtual SD card (Moonraker indexes them)."""
    for name, content in sample_files():
        (stack.gcodes_dir / name).write_bytes(content)


@contextlib.contextmanager
def demo_fleet(
    folder: Path,
    count: int,
    *,
    base_port: int = 0,
    heat_rate: float | None = None,
    forget_history: bool = False,
    progress: Callable[[str], None] = print,
) -> Iterator[list[PrinterStack]]:
    """Start ``count`` virtual printers under ``folder``; stop them all on exit.

    ``forget_history``: each printer's Moonraker database (its job history) is removed
    before it starts, for a demo whose queue starts afresh too: otherwise the last run's
    prints come back in History without the queued jobs they belonged to."""
    if count < 1:
        raise InvalidInput("A fleet needs at least one printer: use --printers 1 or more.")
    folder.mkdir(parents=True, exist_ok=True)
    lock = filelock.FileLock(folder / "demo.lock", timeout=0)
    try:
        lock.acquire()
    except filelock.Timeout:
        raise LaunchError(
            f"Another KyberCore demo is already running from {folder}. Stop it (Ctrl-C in "
            "its terminal), or start this one with another --dir."
        ) from None
    pid_file = folder / "pids.json"
    try:
        _stop_leftovers(pid_file, progress)
        options = fleet_options(count, base_port, heat_rate)
        for opts in options:
            if opts.port:
                ensure_port_free(opts.port)
        if forget_history:
            for opts in options:
                shutil.rmtree(folder / opts.name / "database", ignore_errors=True)
        stacks = [PrinterStack(replace(opts), folder / opts.name) for opts in options]
        try:
            for stack in stacks:
                stack.start()
                copy_samples(stack)
            pid_file.write_text(json.dumps([pid for s in stacks for pid in s.pids.values()]))
            for stack in stacks:
                progress(f"waiting for {stack.options.name} on {stack.url}")
                stack.wait_ready()
            yield stacks
        finally:
            for stack in stacks:
                stack.stop()
            pid_file.unlink(missing_ok=True)
    finally:
        lock.release()


def write_demo_printers(path: Path, stacks: list[PrinterStack]) -> None:
    """Write printers.json for the demo fleet (replacing an earlier demo's)."""
    write_printers(path, fleet_printers(stacks))


def _stop_leftovers(pid_file: Path, progress: Callable[[str], None]) -> None:
    """Stop the processes a previous demo in this folder started and could not stop."""
    try:
        pids = [int(pid) for pid in json.loads(pid_file.read_text())]
    except (OSError, ValueError, TypeError):
        return
    for pid in pids:
        with contextlib.suppress(OSError):
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
            # Only ours: a PID may have been reused by an unrelated process since.
            if b"kybercore" in cmdline or b"klippy" in cmdline or b"moonraker" in cmdline:
                progress(f"stopping process {pid} left over by an earlier demo")
                os.kill(pid, signal.SIGTERM)
    pid_file.unlink(missing_ok=True)
