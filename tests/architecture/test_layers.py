"""The house rules: which package may import what, and how big a module may grow.

Read from the source (AST), imports inside functions included, so a lazy import cannot slip
past. A rule broken here fails CI: move the code to the package where it belongs instead of
widening a rule.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path
from typing import Final

import pytest

PACKAGE: Final = Path(__file__).resolve().parents[2] / "src" / "kybercore"

# kybercore modules each package may import (prefixes); its own package is always allowed.
ALLOWED: Final[dict[str, tuple[str, ...]]] = {
    # All Moonraker I/O: nothing of KyberCore's but its errors and task helpers.
    "moonraker": ("kybercore.errors", "kybercore.aio"),
    # Pure rules and views: configuration models and Moonraker's object shapes, no I/O.
    "core": ("kybercore.errors", "kybercore.registry.models", "kybercore.moonraker.objects"),
    # printers.json and the fleet's models; files replaced whole (kybercore.files).
    "registry": ("kybercore.errors", "kybercore.aio", "kybercore.files"),
    "fleet": (
        "kybercore.errors", "kybercore.aio", "kybercore.core", "kybercore.moonraker",
        "kybercore.registry",
    ),
    # The database: engine and migrations, nothing of the domain.
    "db": ("kybercore.errors", "kybercore.aio"),
    # The job queue: its pure planner (jobs/rules.py) and the I/O around it. It reads
    # Moonraker's metadata parser's location from sim.runtime.
    "jobs": (
        "kybercore.errors", "kybercore.aio", "kybercore.core", "kybercore.db",
        "kybercore.fleet", "kybercore.moonraker", "kybercore.registry", "kybercore.sim.runtime",
    ),
    # The ledger: job history, state timeline, statistics, metrics. It reads the queue's
    # tables (jobs.tables) and vocabulary, never the queue's workings.
    "ledger": (
        "kybercore.errors", "kybercore.aio", "kybercore.files", "kybercore.core", "kybercore.db",
        "kybercore.fleet", "kybercore.moonraker", "kybercore.registry",
        "kybercore.jobs.models", "kybercore.jobs.tables",
    ),
    # Notifications: events from the fleet and the queue, to webhooks and Apprise. The
    # pure part (models, detector, noise, rules, texts) is held to no I/O below.
    "notify": (
        "kybercore.errors", "kybercore.aio", "kybercore.core", "kybercore.db",
        "kybercore.fleet", "kybercore.moonraker", "kybercore.registry", "kybercore.jobs",
    ),
    "api": (
        "kybercore.errors", "kybercore.aio", "kybercore.files", "kybercore.core", "kybercore.fleet",
        "kybercore.moonraker", "kybercore.registry", "kybercore.jobs", "kybercore.db",
        "kybercore.ledger", "kybercore.notify",
    ),
    "sim": ("kybercore.errors", "kybercore.registry"),
    # Scale-out on NATS: leases, and the ingest and front roles over the fleet. A worker
    # is a process's composition root, as api/app.py is: it opens the ledger's database and
    # runs the ledger of its printers (scale/worker_ledger.py).
    # A front runs the job queue through jobs.printers' protocol (scale/queue.py), and
    # owners do its work with jobs.printers' in-process implementation (scale/ops.py).
    # The notifications run on a front through notify.printers' protocol
    # (scale/front_notify.py); notify knows nothing of NATS.
    "scale": (
        "kybercore.errors", "kybercore.aio", "kybercore.core", "kybercore.fleet",
        "kybercore.moonraker", "kybercore.registry", "kybercore.db", "kybercore.ledger",
        "kybercore.jobs", "kybercore.notify",
    ),
    "cli": ("kybercore",),
}  # fmt: skip

# Third-party and standard modules a package must not import.
FORBIDDEN: Final[dict[str, tuple[str, ...]]] = {
    "moonraker": ("fastapi", "starlette", "typer", "uvicorn", "rich"),
    "core": (
        "asyncio", "httpx", "picows", "websockets", "fastapi", "starlette", "typer", "uvicorn",
        "filelock", "socket", "subprocess",
    ),
    "registry": ("fastapi", "starlette", "typer", "uvicorn", "httpx", "picows"),
    # The domain speaks in errors and outcomes; HTTP statuses are api/'s business.
    "fleet": ("fastapi", "starlette", "typer", "uvicorn", "http"),
    "api": ("typer", "rich"),
    "sim": ("fastapi", "starlette", "typer", "uvicorn"),
    "cli": (),
    "db": ("fastapi", "starlette", "typer", "uvicorn", "httpx", "picows"),
    "jobs": ("fastapi", "starlette", "typer", "uvicorn", "http"),
    "ledger": ("fastapi", "starlette", "typer", "uvicorn", "http"),
    "notify": ("fastapi", "starlette", "typer", "uvicorn", "http"),
    "scale": ("fastapi", "starlette", "typer", "uvicorn", "http"),
}  # fmt: skip

# Modules that decide without doing: the notifications' pure logic, driven by the service
# with plain data and times, tested without a loop, a socket or a database.
PURE: Final[dict[str, tuple[str, ...]]] = {
    "notify": ("models", "detector", "noise", "rules", "texts"),
}
PURE_FORBIDDEN: Final = ("asyncio", "httpx", "sqlalchemy", "socket", "picows", "apprise", "anyio")

# The style guide says ~100-400 lines; this is the hard stop (the MCU simulator's one class,
# sim/firmware.py, is the largest at 440).
MAX_LINES: Final = 450


def _imports(path: Path) -> Iterator[tuple[int, str]]:
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            # ``from kybercore import x`` imports the module kybercore.x when x is one.
            if node.module == "kybercore":
                for alias in node.names:
                    yield node.lineno, f"kybercore.{alias.name}"
            else:
                yield node.lineno, node.module


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def violations(package_dir: Path, package: str) -> list[str]:
    """Every import in ``package_dir`` that the rules for ``package`` do not allow."""
    found = []
    own = f"kybercore.{package}"
    for path in sorted(package_dir.rglob("*.py")):
        for line, name in _imports(path):
            where = f"{path.relative_to(package_dir.parent)}:{line} imports {name}"
            if name == "kybercore.__version__":
                continue
            if _within(name, "kybercore"):
                if not _within(name, own) and not any(
                    _within(name, allowed) for allowed in ALLOWED[package]
                ):
                    found.append(where)
            elif any(_within(name, banned) for banned in FORBIDDEN[package]):
                found.append(where)
    return found


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_a_package_imports_only_what_its_layer_allows(package: str) -> None:
    assert violations(PACKAGE / package, package) == []


def test_every_package_has_rules() -> None:
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert packages - {"web"} == set(ALLOWED)


def test_the_check_catches_a_forbidden_import(tmp_path: Path) -> None:
    (tmp_path / "bad.py").write_text(
        "import asyncio\nfrom kybercore.fleet.service import FleetService\n"
        "def lazy():\n    from fastapi import FastAPI\n"
    )
    assert len(violations(tmp_path, "core")) == 3


def impure_imports(path: Path) -> list[str]:
    """Every import in ``path`` of a module that does I/O (or runs a loop)."""
    return [
        f"{path.name}:{line} imports {name}"
        for line, name in _imports(path)
        if any(_within(name, banned) for banned in PURE_FORBIDDEN)
    ]


@pytest.mark.parametrize(
    "module", [f"{package}/{name}.py" for package, names in PURE.items() for name in names]
)
def test_the_pure_modules_import_nothing_that_does_io(module: str) -> None:
    path = PACKAGE / module
    assert path.exists(), f"{module} is listed as pure but does not exist"
    assert impure_imports(path) == []


def test_the_purity_check_catches_io(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import asyncio\nfrom sqlalchemy import select\n"
        "def lazy():\n    import httpx.client\n    from socket import socket\n"
    )
    assert len(impure_imports(bad)) == 4


def test_no_module_grows_past_the_size_a_reader_holds_in_mind() -> None:
    sizes = {
        str(path.relative_to(PACKAGE)): len(path.read_text().splitlines())
        for path in PACKAGE.rglob("*.py")
    }
    assert {name: n for name, n in sizes.items() if n > MAX_LINES} == {}
