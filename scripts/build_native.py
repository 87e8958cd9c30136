"""Compile KyberCore's hot path with mypyc into src/kybercore/_native/ (see kybercore/native.py).

Usage: .venv/bin/python scripts/build_native.py [--force]

Quick when the build is current. Needs mypy (mypyc), setuptools and a C compiler with
Python's headers; without them KyberCore runs the same modules as pure Python. The modules
are compiled in a copy of the package, so a build never leaves files among the sources, and
the result is staged beside the old build (the same filesystem) and renamed into place.
"""

from __future__ import annotations

import argparse
import importlib.machinery
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
# The loader's own rules, without installing a build while this one is made.
from kybercore.native import BUILD, MODULES, PACKAGE, check, source_of, write_manifest  # noqa: E402


def build() -> None:
    """Compile :data:`MODULES` and replace the build with the result."""
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    with tempfile.TemporaryDirectory(prefix="kybercore-native-") as tmp:
        work = Path(tmp)
        copy = work / "kybercore"
        shutil.copytree(
            PACKAGE, copy, ignore=shutil.ignore_patterns("_native", "__pycache__", "web")
        )
        sources = [str(source_of(m, copy).relative_to(work)) for m in MODULES]
        done = subprocess.run(
            [sys.executable, "-m", "mypyc", *sources], cwd=work, capture_output=True, text=True
        )
        if done.returncode != 0:
            sys.exit(f"mypyc failed:\n{done.stdout[-4000:]}{done.stderr[-4000:]}")
        staging = BUILD.with_name("_native.new")
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir()
        files: dict[str, str] = {}
        for module in MODULES:
            built = source_of(module, copy).with_name(module.rsplit(".", 1)[1] + suffix)
            shutil.copy2(built, staging / f"{module}{suffix}")
            files[module] = f"{module}{suffix}"
        # mypyc's runtime library, which every compiled module imports by its top-level name.
        for runtime in work.glob(f"*__mypyc{suffix}"):
            shutil.copy2(runtime, staging / runtime.name)
            files[runtime.name.removesuffix(suffix)] = runtime.name
        write_manifest(staging, copy, files)
        # Between these two steps there is no build, and KyberCore runs as pure Python.
        shutil.rmtree(BUILD, ignore_errors=True)
        staging.rename(BUILD)


def main() -> None:
    """Build unless the build is current (``--force``: build anyway)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--force", action="store_true")
    args = parser.parse_args()
    state, _ = check()
    if state.active and not args.force:
        print(f"compiled hot path: current ({state.reason})")
        return
    started = time.monotonic()
    build()
    state, _ = check()
    if not state.active:
        sys.exit(f"compiled hot path: built, but not usable: {state.reason}")
    print(f"compiled hot path: built in {time.monotonic() - started:.0f} s ({state.reason})")


if __name__ == "__main__":
    main()
