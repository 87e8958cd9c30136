"""The dashboard's files (issue 19): gzipped when the browser takes it, cache-busted by a
content token, and nothing outside the web folder ever served."""

from __future__ import annotations

import gzip
import re
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from kybercore.api.app import WEB_DIR, create_app
from kybercore.api.static import (
    IMMUTABLE,
    REVALIDATE,
    accepts_gzip,
    read_bundle,
    safe_path,
)
from kybercore.registry.store import PrinterRegistry, write_printers

IDENTITY = {"Accept-Encoding": "identity"}
GZIP = {"Accept-Encoding": "gzip, deflate"}


@pytest.fixture
async def web(tmp_path: Path) -> AsyncIterator[httpx.AsyncClient]:
    """The app in this process; no lifespan: the dashboard's files need no fleet."""
    path = tmp_path / "printers.json"
    write_printers(path, [])
    app = create_app(PrinterRegistry(path))
    transport = httpx.ASGITransport(app)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
        yield client


async def _raw(
    client: httpx.AsyncClient, url: str, headers: dict[str, str]
) -> tuple[httpx.Response, bytes]:
    """The answer and its body as sent, not decoded by httpx."""
    async with client.stream("GET", url, headers=headers) as answer:
        return answer, b"".join([chunk async for chunk in answer.aiter_raw()])


def _versioned_urls(html: str) -> list[str]:
    return re.findall(r'(?:href|src)="(/static/[^"]+)"', html)


async def test_gzip_when_accepted_and_the_same_bytes(web: httpx.AsyncClient) -> None:
    source = (WEB_DIR / "fleet.js").read_bytes()
    packed, body = await _raw(web, "/static/fleet.js", GZIP)
    assert packed.status_code == 200
    assert packed.headers["content-encoding"] == "gzip"
    assert packed.headers["vary"] == "Accept-Encoding"
    assert packed.headers["content-type"].startswith("text/javascript")
    assert len(body) < len(source)
    assert gzip.decompress(body) == source


async def test_no_gzip_unless_accepted(web: httpx.AsyncClient) -> None:
    source = (WEB_DIR / "fleet.js").read_bytes()
    for headers in (IDENTITY, {"Accept-Encoding": "gzip;q=0, *"}, {"Accept-Encoding": "br"}):
        plain, body = await _raw(web, "/static/fleet.js", headers)
        assert plain.status_code == 200
        assert "content-encoding" not in plain.headers, headers
        assert plain.headers["vary"] == "Accept-Encoding"
        assert body == source


def test_accept_encoding_weights() -> None:
    assert accepts_gzip("gzip")
    assert accepts_gzip("deflate, gzip;q=0.5")
    assert accepts_gzip("*")
    assert not accepts_gzip("")
    assert not accepts_gzip("identity")
    assert not accepts_gzip("gzip;q=0, *;q=1")
    assert not accepts_gzip("gzip;q=bad")


async def test_the_page_points_at_versioned_immutable_files(web: httpx.AsyncClient) -> None:
    page = await web.get("/", headers=GZIP)
    assert page.status_code == 200
    assert page.headers["cache-control"] == REVALIDATE
    assert page.headers["content-encoding"] == "gzip"
    assert "script-src 'self'" in page.headers["content-security-policy"]  # the guard's
    urls = _versioned_urls(page.text)
    token = read_bundle(WEB_DIR).token
    assert urls
    assert all(url.startswith(f"/static/v-{token}/") for url in urls), urls
    for url in urls:
        answer = await web.get(url)
        assert answer.status_code == 200, url
        assert answer.headers["cache-control"] == IMMUTABLE, url


async def test_modules_import_each_other_under_the_prefix(web: httpx.AsyncClient) -> None:
    """Every module the page reaches by relative imports (and uPlot, which charts.js finds
    beside itself) answers under the versioned prefix."""
    page = await web.get("/")
    prefix = _versioned_urls(page.text)[0].rsplit("/", 1)[0] + "/"
    seen: set[str] = set()
    todo = [url.removeprefix(prefix) for url in _versioned_urls(page.text) if url.endswith(".js")]
    todo += ["vendor/uPlot.iife.min.js", "vendor/uPlot.min.css"]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        answer = await web.get(prefix + name)
        assert answer.status_code == 200, name
        assert answer.headers["cache-control"] == IMMUTABLE, name
        if name.endswith(".js"):
            imported = re.findall(r'(?:from|import)\s*\(?\s*"\./([^"]+)"', answer.text)
            todo += [str(Path(name).parent / i).removeprefix("./") for i in imported]
    assert {"fleet.js", "charts.js", "store.js"} <= seen


async def test_plain_and_stale_addresses_still_answer_without_a_long_cache(
    web: httpx.AsyncClient,
) -> None:
    for url in ("/static/fleet.css", "/static/v-0123456789/fleet.css"):
        answer = await web.get(url)
        assert answer.status_code == 200, url
        assert answer.headers["cache-control"] == REVALIDATE, url
        assert answer.content == (WEB_DIR / "fleet.css").read_bytes()


async def test_a_current_copy_is_not_sent_again(web: httpx.AsyncClient) -> None:
    first = await web.get("/static/fleet.css", headers=GZIP)
    again = await web.get(
        "/static/fleet.css", headers={**GZIP, "If-None-Match": first.headers["etag"]}
    )
    assert again.status_code == 304
    assert again.content == b""
    # The uncompressed copy is another representation, with another tag.
    plain = await web.get("/static/fleet.css", headers={**IDENTITY, "If-None-Match": "x"})
    assert plain.status_code == 200
    assert plain.headers["etag"] != first.headers["etag"]


async def test_head_gives_the_headers_only(web: httpx.AsyncClient) -> None:
    answer = await web.head("/static/fleet.css", headers=IDENTITY)
    assert answer.status_code == 200
    assert answer.content == b""
    assert int(answer.headers["content-length"]) == (WEB_DIR / "fleet.css").stat().st_size


def test_the_token_follows_the_content(tmp_path: Path) -> None:
    (tmp_path / "fleet.html").write_text('<script src="/static/app.js"></script>')
    (tmp_path / "app.js").write_text("export const a = 1;")
    first = read_bundle(tmp_path)
    assert read_bundle(tmp_path).token == first.token  # the same files, the same token
    assert first.index is not None
    assert first.index.body == f'<script src="/static/v-{first.token}/app.js"></script>'.encode()
    (tmp_path / "app.js").write_text("export const a = 2;")
    changed = read_bundle(tmp_path)
    assert changed.token != first.token
    (tmp_path / "app.js").write_text("export const a = 1;")
    (tmp_path / "more.js").write_text("")
    assert read_bundle(tmp_path).token not in (first.token, changed.token)


@pytest.mark.parametrize(
    "path",
    [
        "/static/%2e%2e/api/app.py",
        "/static/..%2fapi%2fapp.py",
        "/static/vendor/%2E%2E/%2E%2E/api/app.py",
        "/static/%2Fetc%2Fpasswd",
        "/static/..%5Capi%5Capp.py",
        "/static/v-0123456789/%2e%2e/%2e%2e/errors.py",
        "/static/%2e/fleet.js",
        "/static/",
        "/static/nope.js",
    ],
)
async def test_nothing_outside_the_folder(web: httpx.AsyncClient, path: str) -> None:
    answer = await web.get(path)
    assert answer.status_code == 404, path
    assert answer.json()["error"]["code"] == "not_found"
    assert "import" not in answer.text  # no file content leaked into the message


def test_safe_path() -> None:
    assert safe_path("vendor/uPlot.min.css") == "vendor/uPlot.min.css"
    for bad in ("", "/etc/passwd", "../x", "a/../b", "a//b", "./a", "a\\b", "a\0b", "a/"):
        assert safe_path(bad) is None, bad
