"""The compiled hot path (kybercore/native.py): used only when it was built from the sources
as they are, and the pure modules it stands in for pass the same tests."""

from __future__ import annotations

import importlib.machinery
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import kybercore.core.view
from kybercore import native
from kybercore.native import MANIFEST, MODULES, check, source_of

ROOT = Path(__file__).resolve().parents[1]
SUFFIX = importlib.machinery.EXTENSION_SUFFIXES[0]


def fake_build(tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the compiled modules' sources and a build that matches them (its files
    are placeholders: check() reads the manifest and the sources, it loads nothing)."""
    package, build = tmp_path / "kybercore", tmp_path / "_native"
    build.mkdir()
    files = {}
    for module in MODULES:
        source = source_of(module, package)
        source.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(source_of(module), source)
        files[module] = f"{module}{SUFFIX}"
        (build / files[module]).write_bytes(b"")
    native.write_manifest(build, package, files)
    return package, build


def test_a_build_stands_in_only_for_the_sources_it_was_built_from(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("KYBERCORE_NATIVE", raising=False)
    package, build = fake_build(tmp_path)
    state, files = check(build, package)
    assert state.active, state.reason
    assert set(files) == set(MODULES)

    # An edited source: the pure module runs until the next build.
    view = source_of("kybercore.core.view", package)
    view.write_text(view.read_text(encoding="utf-8") + "\n# edited\n", encoding="utf-8")
    state, files = check(build, package)
    assert (state.active, files) == (False, {})
    assert state.reason == "view.py changed since the build: build again"


def test_a_build_for_another_python_an_incomplete_one_or_none_is_not_used(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("KYBERCORE_NATIVE", raising=False)
    package, build = fake_build(tmp_path)
    manifest = json.loads((build / MANIFEST).read_text(encoding="utf-8"))

    (build / MANIFEST).write_text(json.dumps({**manifest, "suffix": ".cpython-39.so"}))
    assert check(build, package)[0].reason == f"built for .cpython-39.so, not {SUFFIX}"

    (build / MANIFEST).write_text(json.dumps(manifest))
    (build / f"kybercore.core.numbers{SUFFIX}").unlink()
    assert check(build, package)[0].reason == "the build is incomplete: build again"

    (build / MANIFEST).write_text("{half a manifest")
    assert check(build, package)[0].reason.startswith("unreadable build manifest")

    (build / MANIFEST).unlink()
    assert check(build, package)[0].reason == "not built (scripts/build_native.py)"

    monkeypatch.setenv("KYBERCORE_NATIVE", "0")
    assert check(build, package)[0].reason == "turned off (KYBERCORE_NATIVE=0)"


@pytest.mark.skipif(os.environ.get("CI") != "true", reason="CI builds the compiled modules")
def test_ci_runs_the_compiled_modules() -> None:
    # scripts/bootstrap.sh builds them: this fails if the build broke (mypyc, a compiler).
    assert native.STATE.active, native.STATE.reason
    assert isinstance(kybercore.core.view.__loader__, importlib.machinery.ExtensionFileLoader)


@pytest.mark.skipif(not native.STATE.active, reason="the compiled modules are not in use")
def test_the_pure_modules_pass_the_same_tests() -> None:
    # The whole suite ran compiled; the tests of the compiled modules run once more without.
    assert not source_of("kybercore.core.view").with_suffix(SUFFIX).exists()  # never beside
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
         "tests/core", "tests/moonraker/test_objects.py"],
        cwd=ROOT,
        env={**os.environ, "KYBERCORE_NATIVE": "0", "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}"},
        capture_output=True,
        text=True,
        timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:]
    assert " passed" in done.stdout
