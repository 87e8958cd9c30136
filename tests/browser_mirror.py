"""A test client of KyberCore's `/ws` that keeps the fleet state as a browser would."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import Callable
from typing import Any

import websockets
from websockets.asyncio.client import ClientConnection

from kybercore.moonraker.objects import merge_status
from tests.helpers import wait_for


class BrowserMirror:
    """Receives every frame, applies snapshots and deltas, records timings and raw text."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.printers: dict[str, dict[str, Any]] = {}
        self.frames: list[dict[str, Any]] = []
        self.raw: list[str] = []
        self.received_at: list[float] = []
        self._ws: ClientConnection | None = None
        self._task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> BrowserMirror:
        self._ws = await websockets.connect(self.url)
        self._task = asyncio.create_task(self._read(self._ws))
        await self.wait(lambda: any(f["type"] == "snapshot" for f in self.frames), what="snapshot")
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        if self._ws is not None:
            await self._ws.close()

    async def send(self, message: dict[str, Any]) -> None:
        """Send a control message (e.g. a console subscription)."""
        assert self._ws is not None
        await self._ws.send(json.dumps(message))

    async def _read(self, ws: ClientConnection) -> None:
        async for message in ws:
            # Binary frames of UTF-8 JSON, as KyberCore sends them (not re-encoded per client).
            assert isinstance(message, bytes)
            text = message.decode()
            frame = json.loads(text)
            self.raw.append(text)
            self.frames.append(frame)
            self.received_at.append(time.monotonic())
            if frame["type"] == "snapshot":
                # With a view: slim summaries in "printers", full views of the view in "full".
                printers = {p["id"]: p for p in frame["printers"]}
                self.printers = printers | {p["id"]: p for p in frame.get("full", [])}
            elif frame["type"] == "views":
                self.printers = self.printers | {p["id"]: p for p in frame["printers"]}
            elif frame["type"] == "delta":
                merged = merge_status(self.printers, frame["printers"])
                merged = merge_status(merged, frame.get("full", {}))
                for removed in frame["removed"]:
                    merged.pop(removed, None)
                self.printers = merged

    async def wait(
        self, predicate: Callable[[], bool], timeout: float = 10.0, what: str = "condition"
    ) -> float:
        """Wait until ``predicate()`` holds; return how long it took."""
        return await wait_for(predicate, timeout, f"/ws: {what}")

    def events(self, kind: str, printer: str | None = None) -> list[dict[str, Any]]:
        """Event frames of one type, optionally for one printer."""
        return [
            f
            for f in self.frames
            if f["type"] == kind and (printer is None or f.get("printer") == printer)
        ]
