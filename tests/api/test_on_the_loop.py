"""Every route and every dependency it has runs on the event loop.

FastAPI runs a plain function or a class (as an endpoint or a dependency) in its thread
pool; each such call waits for the busy loop and the GIL twice. The role check and the
service dependencies did that on every ``GET /api/printers``, and were most of the fleet
view's p99 at N = 1,000 (issue 20). Blocking work belongs in an explicit
``asyncio.to_thread`` where it is, never hidden in a signature.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from fastapi.dependencies.models import Dependant
from fastapi.routing import iter_route_contexts

from kybercore.api.app import create_app
from kybercore.registry.store import PrinterRegistry


def _runs_on_the_loop(call: Callable[..., Any] | None) -> bool:
    if call is None:
        return True
    if inspect.iscoroutinefunction(call) or inspect.isasyncgenfunction(call):
        return True
    # An instance with an ``async def __call__`` (FastAPI's own security schemes).
    return not inspect.isclass(call) and inspect.iscoroutinefunction(type(call).__call__)


def _calls(dependant: Dependant) -> Iterator[Callable[..., Any] | None]:
    for sub in dependant.dependencies:
        yield sub.call
        yield from _calls(sub)


def test_no_route_or_dependency_runs_in_the_thread_pool(tmp_path: Path) -> None:
    app = create_app(PrinterRegistry(tmp_path / "printers.json"))
    seen, off_the_loop = 0, []
    for route in iter_route_contexts(app.routes):
        dependant = getattr(route, "dependant", None)
        if dependant is None:  # the schema and the docs' static files: Starlette's own
            continue
        seen += 1
        for call in (route.endpoint, *_calls(dependant)):
            if not _runs_on_the_loop(call):
                off_the_loop.append(f"{route.path}: {getattr(call, '__qualname__', call)}")
    assert seen > 50, "the routes were not found: FastAPI's route listing changed"
    assert off_the_loop == []


def test_the_check_sees_a_class_dependency() -> None:
    class Filters:
        def __init__(self, printer: str | None = None) -> None:
            self.printer = printer

    def plain() -> int:
        return 1

    async def coroutine() -> int:
        return 1

    assert not _runs_on_the_loop(Filters)
    assert not _runs_on_the_loop(plain)
    assert _runs_on_the_loop(coroutine)
