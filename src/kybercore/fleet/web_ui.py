"""Whether a printer's host serves Mainsail or Fluidd, for an "Open in Mainsail" link.

Both are static pages served on the printer's host (usually by nginx on port 80) next to
Moonraker, whose port is elsewhere; the page's ``<title>`` names it. One short request per
host, remembered for a while: a printer page opened a hundred times asks once.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final, Literal
from urllib.parse import urlsplit, urlunsplit

import httpx

from kybercore.aio import Remembered

WebUiKind = Literal["mainsail", "fluidd"]

_TITLE: Final = re.compile(rb"<title[^>]*>([^<]{0,200})</title>", re.IGNORECASE)
_READ_AT_MOST: Final = 64 * 1024
_TIMEOUT: Final = 2.0
_REMEMBER_SECONDS: Final = 300.0


@dataclass(frozen=True, slots=True)
class WebUi:
    """A web interface found on a printer's host."""

    kind: WebUiKind
    url: str


def kind_of(page: bytes) -> WebUiKind | None:
    """Mainsail or Fluidd, from the start of an HTML page; ``None`` for anything else."""
    match = _TITLE.search(page)
    title = match.group(1).lower() if match else b""
    if b"mainsail" in title:
        return "mainsail"
    if b"fluidd" in title:
        return "fluidd"
    return None


def root_of(moonraker_url: str) -> str:
    """``http://host:7125`` → ``http://host/``: where the web interface would be."""
    parts = urlsplit(moonraker_url)
    host = parts.hostname or ""
    netloc = f"[{host}]" if ":" in host else host
    return urlunsplit((parts.scheme, netloc, "/", "", ""))


class WebUiFinder:
    """Probes hosts for a web interface, remembering each answer (found or not) a while."""

    def __init__(self, http: httpx.AsyncClient) -> None:
        self._http = http
        self._known: Remembered[str, WebUi | None] = Remembered(_REMEMBER_SECONDS)

    async def find(self, moonraker_url: str) -> WebUi | None:
        """The interface on ``moonraker_url``'s host, or ``None`` (also when unreachable)."""
        root = root_of(moonraker_url)
        return await self._known.get(root, lambda: self._probe(root))

    async def _probe(self, root: str) -> WebUi | None:
        try:
            async with self._http.stream("GET", root, timeout=_TIMEOUT) as response:
                if response.status_code != 200:
                    return None
                page = b""
                async for chunk in response.aiter_bytes():
                    page += chunk
                    if len(page) >= _READ_AT_MOST:
                        break
        except httpx.HTTPError:
            return None
        kind = kind_of(page)
        return WebUi(kind, root) if kind else None
