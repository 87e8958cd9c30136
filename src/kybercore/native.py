"""The compiled hot path: the same modules, built with mypyc, used when they are current.

Merging Moonraker's deltas, fusing and diffing the views runs for every update of every
printer (``bench/README.md``); compiled with mypyc from the very same sources it costs about
a third less. ``scripts/build_native.py`` (run by ``scripts/bootstrap.sh``) builds them into
``kybercore/_native/`` with a manifest of the sources' hashes. :func:`install` puts them in
front of the pure-Python modules only when every hash still matches, all or none (the
compiled modules call each other directly), so an edited source is never shadowed by a stale
build: the pure module runs until the next build. ``KYBERCORE_NATIVE=0`` turns it off.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Final

MODULES: Final = (
    "kybercore.core.numbers",
    "kybercore.core.progress",
    "kybercore.core.view",
    "kybercore.moonraker.objects",
)
"""What is compiled: the pure code every status update runs through."""

PACKAGE: Final = Path(__file__).resolve().parent
BUILD: Final = PACKAGE / "_native"
MANIFEST: Final = "manifest.json"


@dataclass(frozen=True)
class NativeState:
    """Whether the compiled modules are in use, and if not, why (for the logs and benches)."""

    active: bool
    reason: str


def source_of(module: str, package: Path = PACKAGE) -> Path:
    """The ``.py`` file of one of :data:`MODULES` under ``package`` (``kybercore/``)."""
    return package.joinpath(*module.split(".")[1:]).with_suffix(".py")


def digest(path: Path) -> str:
    """The SHA-256 of a source file, as the manifest records it."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_manifest(build: Path, package: Path, files: dict[str, str]) -> None:
    """Record in ``build`` what it was built from: this Python's extension suffix, the hash
    of each module's source under ``package``, and each module's file (names in ``build``).
    :func:`check` reads exactly this."""
    manifest = {
        "suffix": importlib.machinery.EXTENSION_SUFFIXES[0],
        "sources": {m: digest(source_of(m, package)) for m in MODULES},
        "files": files,
    }
    (build / MANIFEST).write_text(json.dumps(manifest, indent=2), encoding="utf-8")


class _Finder(importlib.abc.MetaPathFinder):
    """Finds the compiled modules (and mypyc's runtime library) by their full names."""

    def __init__(self, files: dict[str, Path]) -> None:
        self.files = files

    def find_spec(
        self, fullname: str, path: object = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        file = self.files.get(fullname)
        if file is None:
            return None
        loader = importlib.machinery.ExtensionFileLoader(fullname, str(file))
        return importlib.util.spec_from_file_location(fullname, file, loader=loader)


def check(build: Path = BUILD, package: Path = PACKAGE) -> tuple[NativeState, dict[str, Path]]:
    """Whether the build in ``build`` may stand in for the sources under ``package``, and
    the file of each module it holds (empty unless it may)."""
    if os.environ.get("KYBERCORE_NATIVE", "1") == "0":
        return NativeState(False, "turned off (KYBERCORE_NATIVE=0)"), {}
    try:
        manifest = json.loads((build / MANIFEST).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return NativeState(False, "not built (scripts/build_native.py)"), {}
    except (OSError, ValueError) as exc:
        return NativeState(False, f"unreadable build manifest ({exc})"), {}
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    if manifest.get("suffix") != suffix:
        return NativeState(False, f"built for {manifest.get('suffix')}, not {suffix}"), {}
    sources: dict[str, str] = manifest.get("sources", {})
    if set(sources) != set(MODULES):
        return NativeState(False, "built from another module list: build again"), {}
    for module, expected in sources.items():
        source = source_of(module, package)
        if not source.is_file() or digest(source) != expected:
            return NativeState(False, f"{source.name} changed since the build: build again"), {}
    files = {name: build / file for name, file in manifest.get("files", {}).items()}
    if not set(MODULES) <= set(files) or not all(file.is_file() for file in files.values()):
        return NativeState(False, "the build is incomplete: build again"), {}
    return NativeState(True, f"{len(MODULES)} modules compiled with mypyc"), files


STATE = NativeState(False, "not installed")
"""What :func:`install` decided for this process."""


def install() -> NativeState:
    """Put the compiled modules in front of the pure ones when the build is current (before
    any of them is imported: ``kybercore/__init__.py`` calls this first)."""
    global STATE
    if any(module in sys.modules for module in MODULES):
        STATE = NativeState(False, "the pure modules were imported first")
        return STATE
    STATE, files = check()
    if STATE.active:
        sys.meta_path.insert(0, _Finder(files))
    return STATE
