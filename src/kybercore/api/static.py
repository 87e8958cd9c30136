"""The dashboard's files (issue 19): compressed once, and cache-busted on every upgrade.

- ``/``: fleet.html, its ``/static/...`` references rewritten to ``/static/v-<token>/...``;
  ``no-cache``, so the browser asks again on every load and sees an upgrade at once.
- ``/static/v-<token>/<path>``: cached for a year (``immutable``). The token is a hash of
  every file's content, so any change gives new addresses and a page never mixes old and
  new modules. The ES modules import each other by relative paths, and ``charts.js`` finds
  the vendored uPlot from ``import.meta.url``: they all stay under the same prefix.
- ``/static/<path>``: the same files, ``no-cache`` (bookmarks, scripts, old tabs). So is a
  versioned address whose token is not the current one: a tab opened before an upgrade
  still gets its lazily imported modules, but no cache keeps them under the old token.

The files are read, hashed and gzipped once, in a worker thread, on the first request;
after that every answer comes from memory (the folder is about half a megabyte). Any path
not read then is a 404, so nothing outside the folder can ever be served.
"""

from __future__ import annotations

import asyncio
import gzip
import hashlib
import mimetypes
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Final

from fastapi import FastAPI, Request
from fastapi.responses import Response

from kybercore.errors import FileNotFound

INDEX: Final = "fleet.html"
PREFIX: Final = "/static/"
IMMUTABLE: Final = "public, max-age=31536000, immutable"
REVALIDATE: Final = "no-cache"
TOKEN_LENGTH: Final = 10
_VERSIONED: Final = re.compile(rf"v-([0-9a-f]{{{TOKEN_LENGTH}}})")
_COMPRESSIBLE: Final = frozenset({".html", ".js", ".mjs", ".css", ".svg", ".json", ".md", ".txt"})
# Explicit: the system's mime.types may call JavaScript application/x-javascript, or lack it.
_TYPES: Final = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".mjs": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
    ".json": "application/json",
    ".md": "text/markdown; charset=utf-8",
}


@dataclass(frozen=True, slots=True)
class Asset:
    """One file as served: its bytes, gzipped bytes (when that helps), type and tag."""

    body: bytes
    gzipped: bytes | None
    media_type: str
    etag: str


@dataclass(frozen=True, slots=True)
class WebBundle:
    """Every dashboard file in memory, the content token, and the rewritten index page."""

    token: str
    files: Mapping[str, Asset]
    index: Asset | None


def content_token(files: Mapping[str, bytes]) -> str:
    """A short hash of the files' names and contents: it changes whenever any of them does."""
    digest = hashlib.sha256()
    for name in sorted(files):
        digest.update(name.encode() + b"\0" + hashlib.sha256(files[name]).digest())
    return digest.hexdigest()[:TOKEN_LENGTH]


def safe_path(path: str) -> str | None:
    """``path`` as a relative POSIX path inside the folder, or None for anything that could
    leave it or is ambiguous (``..``, absolute, backslashes, empty segments, NUL)."""
    if not path or "\\" in path or "\0" in path or path.startswith("/"):
        return None
    parts = path.split("/")
    if any(part in ("", ".", "..") for part in parts):
        return None
    return str(PurePosixPath(*parts))


def make_asset(name: str, body: bytes) -> Asset:
    """``body`` ready to serve as the file ``name``: compressed once if its type gains."""
    suffix = PurePosixPath(name).suffix.lower()
    media_type = _TYPES.get(suffix) or mimetypes.guess_type(name)[0] or "application/octet-stream"
    gzipped = None
    if suffix in _COMPRESSIBLE:
        # mtime=0: the same file gives the same bytes, run after run.
        packed = gzip.compress(body, compresslevel=9, mtime=0)
        gzipped = packed if len(packed) < len(body) else None
    return Asset(body, gzipped, media_type, hashlib.sha256(body).hexdigest()[:16])


def versioned_index(html: bytes, token: str) -> bytes:
    """The index page with every ``"/static/...`` reference under the versioned prefix."""
    return html.replace(f'"{PREFIX}'.encode(), f'"{PREFIX}v-{token}/'.encode())


def read_bundle(folder: Path) -> WebBundle:
    """Read, hash and compress every file under ``folder`` (blocking: run it in a thread).
    A missing folder is an empty bundle: every path is then a 404."""
    raw: dict[str, bytes] = {}
    if folder.is_dir():
        for path in sorted(folder.rglob("*")):
            name = path.relative_to(folder).as_posix()
            if path.is_file() and not any(part.startswith(".") for part in name.split("/")):
                raw[name] = path.read_bytes()
    token = content_token(raw)
    files = {name: make_asset(name, body) for name, body in raw.items()}
    index = make_asset(INDEX, versioned_index(raw[INDEX], token)) if INDEX in raw else None
    return WebBundle(token, files, index)


def accepts_gzip(accept_encoding: str) -> bool:
    """Whether an ``Accept-Encoding`` value allows gzip (``gzip;q=0`` refuses it, even
    next to ``*``)."""
    weights: dict[str, float] = {}
    for item in accept_encoding.lower().split(","):
        name, _, params = item.strip().partition(";")
        weight = 1.0
        key, _, value = params.strip().partition("=")
        if key.strip() == "q":
            try:
                weight = float(value)
            except ValueError:
                weight = 0.0
        weights[name.strip()] = weight
    return weights.get("gzip", weights.get("*", 0.0)) > 0


def _matches(if_none_match: str | None, etag: str) -> bool:
    if not if_none_match:
        return False
    tags = {tag.strip().removeprefix("W/") for tag in if_none_match.split(",")}
    return "*" in tags or etag in tags


def answer(request: Request, asset: Asset, cache_control: str) -> Response:
    """``asset`` for ``request``: gzipped when accepted, 304 when the browser's copy is
    current, headers only for HEAD."""
    headers = {"Cache-Control": cache_control, "Content-Type": asset.media_type}
    body, etag = asset.body, f'"{asset.etag}"'
    if asset.gzipped is not None:
        # Even an uncompressed answer depends on the header: a shared cache must know.
        headers["Vary"] = "Accept-Encoding"
        if accepts_gzip(request.headers.get("accept-encoding", "")):
            body, etag = asset.gzipped, f'"{asset.etag}-gz"'
            headers["Content-Encoding"] = "gzip"
    headers["ETag"] = etag
    if _matches(request.headers.get("if-none-match"), etag):
        del headers["Content-Type"]
        return Response(status_code=304, headers=headers)
    if request.method == "HEAD":
        headers["Content-Length"] = str(len(body))
        body = b""
    return Response(body, headers=headers)


class WebFiles:
    """The dashboard's files of one app, read the first time they are asked for."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._bundle: WebBundle | None = None
        self._lock = asyncio.Lock()

    async def bundle(self) -> WebBundle:
        """The files in memory; read (once, off the event loop) on the first call."""
        if self._bundle is None:
            async with self._lock:
                if self._bundle is None:
                    self._bundle = await asyncio.to_thread(read_bundle, self.folder)
        return self._bundle

    async def index(self, request: Request) -> Response:
        """``/``: the dashboard page, pointing at the current versioned files."""
        bundle = await self.bundle()
        if bundle.index is None:
            raise FileNotFound(f"The dashboard page is missing from {self.folder}.")
        return answer(request, bundle.index, REVALIDATE)

    async def static(self, request: Request, path: str) -> Response:
        """``/static/[v-<token>/]<path>``: one file, immutable under the current token."""
        bundle = await self.bundle()
        cache_control = REVALIDATE
        first, _, rest = path.partition("/")
        versioned = _VERSIONED.fullmatch(first)
        if versioned and rest:
            path = rest
            if versioned.group(1) == bundle.token:
                cache_control = IMMUTABLE
        name = safe_path(path)
        asset = bundle.files.get(name) if name is not None else None
        if asset is None:
            shown = path[:100].encode("unicode_escape").decode()
            raise FileNotFound(f"No dashboard file '{shown}'. The dashboard is at /.")
        return answer(request, asset, cache_control)


def add_web(app: FastAPI, folder: Path) -> WebFiles:
    """Serve the dashboard in ``folder`` at ``/`` and ``/static/``; returns its files."""
    web = WebFiles(folder)
    app.add_api_route("/", web.index, methods=["GET", "HEAD"], include_in_schema=False)
    app.add_api_route(
        PREFIX + "{path:path}", web.static, methods=["GET", "HEAD"], include_in_schema=False
    )
    return web
