"""The OpenAPI schema describes what the API really accepts, so generated clients and
fuzzers see the truth: Moonraker URLs, file paths and API keys carry the patterns their
validators apply, and the patterns agree with the validators."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from kybercore.api.app import create_app
from kybercore.core.paths import MAX_PATH, SAFE_PATH_PATTERN, safe_path
from kybercore.errors import InvalidInput
from kybercore.registry.models import URL_PATTERN, PrinterConfig
from kybercore.registry.store import PrinterRegistry


@pytest.fixture(scope="module")
def schema(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    folder = tmp_path_factory.mktemp("openapi")
    return create_app(PrinterRegistry(Path(folder) / "printers.json")).openapi()


def _string(prop: dict[str, Any]) -> dict[str, Any]:
    """The string branch of a property (``X | None`` is an anyOf)."""
    return next((s for s in prop.get("anyOf", [prop]) if s.get("type") == "string"), prop)


def test_moonraker_urls_and_api_keys_are_described_as_validated(schema: dict[str, Any]) -> None:
    models = schema["components"]["schemas"]
    for model in ("PrinterCreate", "PrinterUpdate", "PrinterView"):
        url = _string(models[model]["properties"]["moonraker_url"])
        assert url["pattern"] == URL_PATTERN, model
        assert url["format"] == "uri", model
        assert url["maxLength"] == 2048, model
    for model in ("PrinterCreate", "PrinterUpdate"):
        key = _string(models[model]["properties"]["api_key"])
        assert key["pattern"] == "^[!-~]*$", model


def test_file_paths_are_described_as_validated(schema: dict[str, Any]) -> None:
    filename = _string(schema["components"]["schemas"]["ActionRequest"]["properties"]["filename"])
    assert (filename["pattern"], filename["maxLength"]) == (SAFE_PATH_PATTERN, MAX_PATH)
    files = "/api/printers/{printer_id}/files"
    for path, method, name in (
        (files, "delete", "path"),
        (f"{files}/metadata", "get", "filename"),
        (f"{files}/thumbnail", "get", "path"),
    ):
        params = {p["name"]: p["schema"] for p in schema["paths"][path][method]["parameters"]}
        assert params[name]["pattern"] == SAFE_PATH_PATTERN, (path, name)
        assert params[name]["maxLength"] == MAX_PATH, (path, name)


def test_a_thumbnail_is_documented_as_the_image_it_is(schema: dict[str, Any]) -> None:
    ok = schema["paths"]["/api/printers/{printer_id}/files/thumbnail"]["get"]["responses"]["200"]
    assert set(ok["content"]) == {"image/png", "image/jpeg"}


def _accepted(path: str) -> bool:
    try:
        safe_path(path)
    except InvalidInput:
        return False
    return True


@given(st.text(alphabet=st.sampled_from("ab./\\\x00\x1f \x7fé"), max_size=12))
@settings(max_examples=500)
def test_the_path_pattern_is_exactly_safe_path(path: str) -> None:
    assert bool(re.fullmatch(SAFE_PATH_PATTERN, path)) == _accepted(path), repr(path)


@given(st.from_regex(SAFE_PATH_PATTERN, fullmatch=True).filter(lambda p: len(p) <= MAX_PATH))
@settings(max_examples=200)
def test_paths_generated_from_the_pattern_are_accepted(path: str) -> None:
    assert safe_path(path) == path


def _url_accepted(url: str) -> bool:
    try:
        PrinterConfig(id="p", name="P", moonraker_url=url)
    except ValidationError:
        return False
    return True


@given(
    scheme=st.sampled_from(["http", "HTTPS", "ftp", ""]),
    host=st.text(alphabet=st.sampled_from("ab1.-:[]@ %\\\x01é"), max_size=8),
    port=st.none() | st.text(alphabet=st.sampled_from("0123456789x"), max_size=6),
    path=st.text(alphabet=st.sampled_from("a/ ?#@\x1f\x7f"), max_size=5),
)
@settings(max_examples=1000)
def test_the_url_pattern_agrees_with_the_validator(
    scheme: str, host: str, port: str | None, path: str
) -> None:
    url = f"{scheme}://{host}" + (f":{port}" if port is not None else "") + path
    matches, accepted = bool(re.fullmatch(URL_PATTERN, url)), _url_accepted(url)
    # Only a port's range and an IPv6 address's validity are beyond the pattern: a match is
    # refused for nothing else.
    out_of_range = port is not None and port.isdigit() and int(port) > 65535
    assert matches == accepted or (matches and (out_of_range or host.startswith("["))), url
