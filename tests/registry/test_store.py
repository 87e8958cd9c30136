"""printers.json: models, validation, located errors, atomic writes, locking, hot reload."""

from __future__ import annotations

import asyncio
import itertools
import json
import multiprocessing
import os
import re
import stat
import threading
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from kybercore.errors import ConfigError, InvalidInput, UnknownPrinter
from kybercore.registry.models import (
    SLUG_PATTERN,
    PrinterConfig,
    PrinterCreate,
    PrinterUpdate,
    slugify,
)
from kybercore.registry.store import (
    PrinterRegistry,
    default_printers_path,
    read_printers,
    write_printers,
)
from tests.helpers import wait_for

SECRET = "s3cr3t-moonraker-key-0123456789"


_ports = itertools.count(20000)


def new(name: str, **fields: Any) -> PrinterCreate:
    """A new printer on a Moonraker of its own (one Moonraker drives one printer)."""
    return PrinterCreate.model_validate(
        {"name": name, "moonraker_url": f"http://10.0.0.5:{next(_ports)}", **fields}
    )


def config(**fields: Any) -> PrinterConfig:
    return PrinterConfig.model_validate(
        {"id": "p1", "name": "P1", "moonraker_url": "http://h:7125", **fields}
    )


def write_json(path: Path, printers: list[dict[str, Any]]) -> None:
    path.write_text(json.dumps({"version": 1, "printers": printers}, indent=2) + "\n")


def line_of(path: Path, fragment: str, occurrence: int = 0) -> int:
    """1-based number of the line holding ``fragment`` (its n-th occurrence)."""
    lines = [n for n, text in enumerate(path.read_text().splitlines(), 1) if fragment in text]
    return lines[occurrence]


@pytest.fixture
def path(tmp_path: Path) -> Path:
    return tmp_path / "printers.json"


@pytest.fixture
def registry(path: Path) -> PrinterRegistry:
    return PrinterRegistry(path)


# --- models ---------------------------------------------------------------------------


@pytest.mark.parametrize("bad", ["", "-a", "_a", "A", "a b", "ñu", "a/b", "a" * 65, "a.b"])
def test_bad_slug_rejected(bad: str) -> None:
    with pytest.raises(ValidationError, match="id"):
        config(id=bad)


@pytest.mark.parametrize("good", ["a", "0", "voron-2_4", "a" * 64])
def test_good_slug_accepted(good: str) -> None:
    assert config(id=good).id == good


@pytest.mark.parametrize(
    ("url", "reason"),
    [
        ("ftp://h:7125", "http:// or https://"),
        ("ws://h:7125", "http:// or https://"),
        ("mailto:h", "http:// or https://"),
        ("http://h:7125/server/info", "without a path"),
        ("http://proxy/printers/one/", "without a path"),
        ("h:7125/#/", "http:// or https://"),  # only a bare host[:port] is completed
        ("//h:7125", "http:// or https://"),
        ("http://user:pw@h:7125", "credentials"),
        ("http://user@h", "credentials"),
        ("http://h:7125/?token=x", "query"),
        ("http://h:7125#x", "fragment"),
        ("http://:7125", "no host"),
        ("http://h:99999", "not a valid URL"),
        ("http://h:port", "not a valid URL"),
        (" http://h", "spaces"),
        ("http://h/a b", "spaces"),
    ],
)
def test_bad_url_rejected(url: str, reason: str) -> None:
    with pytest.raises(ValidationError, match=reason):
        config(moonraker_url=url)


@pytest.mark.parametrize(
    ("url", "normalized"),
    [
        ("http://h:7125/", "http://h:7125"),
        ("HTTPS://Printer.LAN", "https://printer.lan"),
        ("http://[::1]:7125/", "http://[::1]:7125"),
        # What people type: host and port, completed to Moonraker's plain HTTP.
        ("192.168.1.50:7125", "http://192.168.1.50:7125"),
        ("Printer.local", "http://printer.local"),
    ],
)
def test_url_normalized(url: str, normalized: str) -> None:
    assert config(moonraker_url=url).moonraker_url == normalized


@given(scheme=st.from_regex(r"[A-Za-z][A-Za-z0-9+.-]{0,8}", fullmatch=True))
@settings(max_examples=50)
def test_only_http_schemes(scheme: str) -> None:
    url = f"{scheme}://host:7125"
    if scheme.lower() in ("http", "https"):
        assert config(moonraker_url=url).moonraker_url == f"{scheme.lower()}://host:7125"
    else:
        with pytest.raises(ValidationError):
            config(moonraker_url=url)


@given(
    host=st.from_regex(r"[a-z0-9]([a-z0-9-]{0,10}[a-z0-9])?(\.[a-z]{2,5}){0,2}", fullmatch=True),
    port=st.none() | st.integers(1, 65535),
    scheme=st.sampled_from(["http://", "HTTP://", ""]),
    slash=st.booleans(),
)
@settings(max_examples=100)
def test_valid_urls_normalize_idempotently(
    host: str, port: int | None, scheme: str, slash: bool
) -> None:
    address = host + (f":{port}" if port else "")
    normalized = config(moonraker_url=scheme + address + ("/" if slash else "")).moonraker_url
    assert normalized == "http://" + address
    assert config(moonraker_url=normalized).moonraker_url == normalized


@given(st.text(max_size=120))
@settings(max_examples=200)
def test_slugify_always_gives_a_valid_id(name: str) -> None:
    slug = slugify(name)
    assert re.fullmatch(SLUG_PATTERN, slug)
    assert config(id=slug).id == slug


def test_slugify_examples() -> None:
    assert slugify("Impresora Ñandú #2") == "impresora-nandu-2"
    assert slugify("  ") == "printer"


@pytest.mark.parametrize(
    "capabilities",
    [
        {"build_volume": {"x": -1, "y": 200, "z": 200}},
        {"build_volume": {"x": 200, "y": 0, "z": 200}},
        {"build_volume": {"x": 200, "y": 200}},
        {"nozzle_diameter": -0.4},
        {"max_extruder_temp": 0},
        {"max_bed_temp": 1000},
        {"material": ""},
        {"speed": 3},
    ],
)
def test_bad_capabilities_rejected(capabilities: dict[str, Any]) -> None:
    with pytest.raises(ValidationError, match="capabilities"):
        config(capabilities=capabilities)


@pytest.mark.parametrize(
    "fields",
    [
        {"name": ""},
        {"name": "x" * 101},
        {"tags": [""]},
        {"tags": ["x" * 33]},
        {"enabled": "yes"},
        {"colour": "red"},
        {"api_key": "two words"},
        {"api_key": "line\nbreak"},
        {"api_key": "k" * 257},
    ],
)
def test_other_fields_validated(fields: dict[str, Any]) -> None:
    with pytest.raises(ValidationError):
        config(**fields)


def test_tags_deduplicated_in_order() -> None:
    assert config(tags=["b", "a", "b", " a "]).tags == ["b", "a"]


def test_api_key_never_in_public_view_or_repr() -> None:
    printer = config(api_key=SECRET)
    public = printer.public()
    assert public.api_key_set is True
    assert "api_key" not in public.model_dump()
    for text in (public.model_dump_json(), repr(public), repr(printer), str(printer)):
        assert SECRET not in text
    assert printer.to_file_dict()["api_key"] == SECRET
    assert config().public().api_key_set is False


def test_api_key_not_echoed_in_validation_errors() -> None:
    with pytest.raises(ValidationError) as caught:
        config(api_key=SECRET * 20)
    assert SECRET not in str(caught.value)


def test_patch_semantics_for_api_key_and_capabilities() -> None:
    current = config(
        api_key=SECRET, capabilities={"nozzle_diameter": 0.4, "material": "PLA"}, tags=["x"]
    )
    kept = PrinterUpdate.model_validate({"name": "New"}).apply(current)
    assert kept.name == "New"
    assert kept.api_key is not None
    assert kept.api_key.get_secret_value() == SECRET
    assert kept.tags == ["x"]
    for clear in ("", None):
        assert PrinterUpdate.model_validate({"api_key": clear}).apply(current).api_key is None
    replaced = PrinterUpdate.model_validate({"api_key": "other"}).apply(current).api_key
    assert replaced is not None
    assert replaced.get_secret_value() == "other"
    merged = PrinterUpdate.model_validate(
        {"capabilities": {"nozzle_diameter": 0.6, "material": None}}
    ).apply(current)
    assert merged.capabilities.nozzle_diameter == 0.6
    assert merged.capabilities.material is None


@pytest.mark.parametrize(
    "body", [{"name": None}, {"moonraker_url": None}, {"id": "new-id"}, {"enabled": None}]
)
def test_patch_rejects_null_and_id(body: dict[str, Any]) -> None:
    with pytest.raises(ValidationError):
        PrinterUpdate.model_validate(body)


def test_patch_result_is_validated_again() -> None:
    with pytest.raises(ValidationError, match="http"):
        PrinterUpdate.model_validate({"moonraker_url": "ftp://h"}).apply(config())


# --- reading --------------------------------------------------------------------------


def test_missing_file_is_an_empty_fleet(path: Path, registry: PrinterRegistry) -> None:
    assert read_printers(path) == []
    assert registry.reload() == []
    assert not path.exists()


def test_default_path(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("KYBERCORE_PRINTERS", raising=False)
    assert default_printers_path() == Path("printers.json")
    monkeypatch.setenv("KYBERCORE_PRINTERS", str(tmp_path / "fleet.json"))
    assert default_printers_path() == tmp_path / "fleet.json"
    assert PrinterRegistry().path == tmp_path / "fleet.json"


def test_roundtrip(path: Path, registry: PrinterRegistry) -> None:
    full = new(
        "Voron 2.4",
        id="voron",
        model="Voron 2.4 R2",
        location="Sala B",
        tags=["abs", "big"],
        notes="Línea 2\nmulti-line",
        api_key=SECRET,
        enabled=False,
        capabilities={
            "build_volume": {"x": 350, "y": 350, "z": 340},
            "nozzle_diameter": 0.4,
            "material": "ABS",
            "max_extruder_temp": 300,
            "max_bed_temp": 120,
        },
    )
    added = [registry.add(full), registry.add(new("Ender 3"))]
    assert read_printers(path) == added
    assert PrinterRegistry(path).reload() == added
    text = path.read_text()
    assert text.endswith("}\n")
    assert text.startswith('{\n  "version": 1,\n  "printers": [\n')
    stored = json.loads(text)["printers"][0]
    assert list(stored) == list(PrinterConfig.model_fields)
    assert stored["api_key"] == SECRET
    assert stored["location"] == "Sala B"


def test_file_is_private(path: Path, registry: PrinterRegistry) -> None:
    registry.add(new("A", api_key=SECRET))
    assert stat.S_IMODE(path.stat().st_mode) == 0o600


def test_a_stored_key_never_follows_the_printer_to_another_host(
    registry: PrinterRegistry,
) -> None:
    """The key is write-only: whoever edits the URL must give it again for a new host, or
    the next session would send it (X-Api-Key, identify) to a host of their choosing."""
    added = registry.add(new("A", api_key=SECRET, moonraker_url="http://10.0.0.5:7125"))

    def key_after(**fields: Any) -> str | None:
        stored = registry.update(added.id, PrinterUpdate.model_validate(fields))
        return stored.api_key.get_secret_value() if stored.api_key else None

    for elsewhere in ("http://evil.example:7125", "https://10.0.0.5:7125", "http://10.0.0.5:7126"):
        with pytest.raises(InvalidInput, match="API key") as refused:
            registry.update(added.id, PrinterUpdate.model_validate({"moonraker_url": elsewhere}))
        assert {r["code"] for r in refused.value.reasons} == {"api_key_needed"}
        assert registry.get(added.id).moonraker_url == "http://10.0.0.5:7125"
    # Same scheme, host and port (written with a trailing slash, another field): kept.
    assert key_after(moonraker_url="http://10.0.0.5:7125/") == SECRET
    assert key_after(moonraker_url="http://10.0.0.5:7125", name="Renamed") == SECRET
    # Given again, or removed on purpose: the move is fine.
    assert key_after(moonraker_url="http://10.0.0.9:7125", api_key="new-key") == "new-key"
    assert key_after(moonraker_url="http://10.0.0.5:7125", api_key=None) is None
    assert key_after(moonraker_url="http://10.0.0.8:80") is None  # no key, nothing to protect
    assert key_after(moonraker_url="http://10.0.0.8") is None


def test_json_syntax_error_names_file_line_and_column(path: Path) -> None:
    path.write_text('{\n  "version": 1,\n  "printers": [\n    {"id": "a",,}\n  ]\n}\n')
    with pytest.raises(ConfigError) as caught:
        read_printers(path)
    message = caught.value.message
    assert str(path) in message
    assert "line 4, column 16" in message  # the second comma
    assert "printers.json.bak" in message


def test_validation_error_names_line_printer_and_field(path: Path) -> None:
    write_json(
        path,
        [
            {"id": "good", "name": "Good", "moonraker_url": "http://a"},
            {"id": "bad", "name": "Bad", "moonraker_url": "ftp://b"},
        ],
    )
    with pytest.raises(ConfigError) as caught:
        read_printers(path)
    message = caught.value.message
    assert f"{path}, line {line_of(path, 'ftp://')}, column 24:" in message  # the value
    assert "printers[1] (id 'bad'), field 'moonraker_url'" in message
    assert "http:// or https://" in message


def test_missing_field_points_at_the_printer(path: Path) -> None:
    write_json(path, [{"id": "a", "name": "A", "moonraker_url": "http://a"}, {"id": "b"}])
    line = line_of(path, '"id": "b"') - 1  # the line of its opening brace
    expected = rf"line {line}, column 5: printers\[1\] \(id 'b'\), field 'name'"
    with pytest.raises(ConfigError, match=expected):
        read_printers(path)


def test_nested_field_error(path: Path) -> None:
    caps = {"build_volume": {"x": 200, "y": -5, "z": 200}}
    write_json(path, [{"id": "a", "name": "A", "moonraker_url": "http://a", "capabilities": caps}])
    line = line_of(path, '"y": -5')
    with pytest.raises(ConfigError, match=rf"line {line}, .*field 'capabilities.build_volume.y'"):
        read_printers(path)


def test_duplicate_ids_rejected(path: Path) -> None:
    write_json(
        path,
        [
            {"id": "same", "name": "A", "moonraker_url": "http://a"},
            {"id": "same", "name": "B", "moonraker_url": "http://b"},
        ],
    )
    line = line_of(path, '"same"', occurrence=1)
    with pytest.raises(ConfigError, match=rf"line {line}, column 13: printers\[1\]: id 'same'"):
        read_printers(path)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[]", "line 1, column 1: expected"),
        ('{"version": 2, "printers": []}', "version 2"),
        ('{"printers": []}', "missing version None"),
        ('{"version": 1, "printers": {}}', "'printers' must be a list"),
        ('{"version": 1, "printers": [], "extra": 1}', "unexpected key 'extra'"),
        ("", "not valid JSON"),
    ],
)
def test_bad_top_level(path: Path, text: str, expected: str) -> None:
    path.write_text(text)
    with pytest.raises(ConfigError, match=re.escape(expected)):
        read_printers(path)


# --- writing --------------------------------------------------------------------------


def test_add_derives_unique_ids(registry: PrinterRegistry) -> None:
    ids = [registry.add(new("Ender 3")).id for _ in range(3)]
    assert ids == ["ender-3", "ender-3-2", "ender-3-3"]


def test_explicit_id_collision(registry: PrinterRegistry) -> None:
    registry.add(new("A", id="a"))
    with pytest.raises(InvalidInput, match="id 'a' already exists") as caught:
        registry.add(new("Other", id="a"))
    # The dashboard shows the reason in the user's language.
    [reason] = caught.value.reasons
    assert (reason["code"], reason["level"]) == ("id_taken", "block")
    assert "Ya existe una impresora con el id 'a'" in reason["es"]


def test_update_and_remove(path: Path, registry: PrinterRegistry) -> None:
    registry.add(new("A", id="a", api_key=SECRET))
    updated = registry.update("a", PrinterUpdate(location="Lab"))
    assert updated.location == "Lab"
    assert updated.api_key is not None
    assert read_printers(path) == [updated]
    assert registry.get("a") == updated
    assert registry.remove("a") == updated
    assert read_printers(path) == []
    with pytest.raises(UnknownPrinter):
        registry.get("a")


def test_unknown_id(path: Path, registry: PrinterRegistry) -> None:
    registry.add(new("A"))
    before = path.read_bytes()
    with pytest.raises(UnknownPrinter, match="'nope'"):
        registry.update("nope", PrinterUpdate(name="x"))
    with pytest.raises(UnknownPrinter, match="'nope'"):
        registry.remove("nope")
    assert path.read_bytes() == before


def test_backup_holds_previous_version(path: Path, registry: PrinterRegistry) -> None:
    registry.add(new("A"))
    first = path.read_bytes()
    registry.add(new("B"))
    assert Path(f"{path}.bak").read_bytes() == first
    second = path.read_bytes()
    registry.remove("a")
    assert Path(f"{path}.bak").read_bytes() == second


def test_half_written_file_is_reported_and_never_overwritten(
    path: Path, registry: PrinterRegistry
) -> None:
    registry.add(new("A"))
    registry.add(new("B"))
    good = registry.reload()
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) // 2])
    truncated = path.read_bytes()

    assert registry.changed()
    with pytest.raises(ConfigError, match="not valid JSON"):
        registry.reload()
    assert registry.printers == good
    assert registry.last_error is not None
    assert "half-written" in registry.last_error
    with pytest.raises(ConfigError):
        registry.add(new("C"))
    with pytest.raises(ConfigError):
        registry.remove("a")
    assert path.read_bytes() == truncated


def test_failed_write_leaves_old_file_and_no_temp_file(
    path: Path, registry: PrinterRegistry, monkeypatch: pytest.MonkeyPatch
) -> None:
    registry.add(new("A"))
    registry.add(new("B"))
    before = path.read_bytes()
    listing = sorted(p.name for p in path.parent.iterdir())
    assert listing == ["printers.json", "printers.json.bak", "printers.json.lock"]
    real_replace = os.replace

    def failing_replace(src: Any, dst: Any) -> None:
        if str(dst) == str(path):
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(ConfigError, match="No space left on device"):
        registry.add(new("C"))
    assert path.read_bytes() == before
    assert sorted(p.name for p in path.parent.iterdir()) == listing
    assert [p.id for p in registry.printers] == ["a", "b"]


def test_stale_temp_files_are_cleaned(path: Path, registry: PrinterRegistry) -> None:
    registry.add(new("A"))
    stale = path.parent / ".printers.json.killed.tmp"
    stale.write_text("{")
    registry.add(new("B"))
    assert not stale.exists()


def test_threads_lose_nothing(path: Path) -> None:
    shared = PrinterRegistry(path)

    def add_many(thread: int) -> None:
        own = PrinterRegistry(path)  # half the writes through another instance
        for i in range(5):
            (shared if i % 2 else own).add(new(f"t{thread}", id=f"t{thread}-{i}"))

    threads = [threading.Thread(target=add_many, args=(n,)) for n in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    ids = {p.id for p in read_printers(path)}
    assert ids == {f"t{t}-{i}" for t in range(8) for i in range(5)}


def _add_from_process(path: str, worker: int, count: int) -> None:
    registry = PrinterRegistry(path)
    for i in range(count):
        url = f"http://10.0.{worker}.{i}:7125"
        registry.add(new(f"w{worker}", id=f"w{worker}-{i}", moonraker_url=url))


def test_processes_lose_nothing(path: Path) -> None:
    context = multiprocessing.get_context("spawn")
    workers = [context.Process(target=_add_from_process, args=(str(path), w, 10)) for w in range(3)]
    for worker in workers:
        worker.start()
    _add_from_process(str(path), 99, 10)  # this process writes at the same time
    for worker in workers:
        worker.join(timeout=30)
        assert worker.exitcode == 0
    ids = {p.id for p in read_printers(path)}
    assert ids == {f"w{w}-{i}" for w in (0, 1, 2, 99) for i in range(10)}


# --- hot reload -----------------------------------------------------------------------


def test_own_writes_are_not_external_changes(registry: PrinterRegistry) -> None:
    registry.reload()
    registry.add(new("A"))
    assert not registry.changed()


def test_external_edit_detected_and_reloaded(path: Path, registry: PrinterRegistry) -> None:
    registry.add(new("A", id="a"))
    assert not registry.changed()
    PrinterRegistry(path).add(new("B", id="b"))  # e.g. the CLI
    assert registry.changed()
    assert [p.id for p in registry.reload()] == ["a", "b"]
    assert not registry.changed()


def test_broken_edit_reported_once_and_last_good_kept(
    path: Path, registry: PrinterRegistry
) -> None:
    registry.add(new("A", id="a"))
    good = registry.printers
    text = path.read_text()
    path.write_text(text.replace(registry.get("a").moonraker_url, "ftp://10.0.0.5"))
    assert registry.changed()
    with pytest.raises(ConfigError, match="field 'moonraker_url'"):
        registry.reload()
    assert registry.printers == good
    assert not registry.changed()  # the same broken file is not reported again
    path.write_text(text.replace('"A"', '"Renamed"'))
    assert registry.changed()
    assert registry.reload()[0].name == "Renamed"
    assert registry.last_error is None


def test_write_merging_an_external_edit_is_still_reported(
    path: Path, registry: PrinterRegistry
) -> None:
    registry.add(new("A", id="a"))
    PrinterRegistry(path).add(new("B", id="b"))
    registry.add(new("C", id="c"))  # absorbs b
    assert registry.changed()
    assert [p.id for p in registry.reload()] == ["a", "b", "c"]


async def test_watch_reports_good_and_bad_edits(path: Path, registry: PrinterRegistry) -> None:
    registry.add(new("A", id="a"))
    changes: asyncio.Queue[list[PrinterConfig]] = asyncio.Queue()
    errors: asyncio.Queue[ConfigError] = asyncio.Queue()

    async def on_change(printers: list[PrinterConfig]) -> None:
        await changes.put(printers)

    checks = 0
    changed = registry.changed

    def counting_changed() -> bool:
        nonlocal checks
        checks += 1
        return changed()

    registry.changed = counting_changed  # type: ignore[method-assign]
    task = asyncio.create_task(registry.watch(on_change, errors.put_nowait, interval=0.01))
    try:
        await asyncio.to_thread(PrinterRegistry(path).add, new("B", id="b"))
        printers = await asyncio.wait_for(changes.get(), 5)
        assert [p.id for p in printers] == ["a", "b"]

        path.write_text('{"version": 1, "printers": [')
        error = await asyncio.wait_for(errors.get(), 5)
        assert "not valid JSON" in error.message
        assert [p.id for p in registry.printers] == ["a", "b"]

        # The same broken file is not reported again, however often the file is checked.
        seen = checks
        await wait_for(lambda: checks >= seen + 5, what="five more checks of the file")
        assert changes.empty()
        assert errors.empty()
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task


def test_one_moonraker_is_one_printer(registry: PrinterRegistry) -> None:
    """A second printer on a Moonraker already in the fleet is refused, however the URL is
    spelled, on add and on edit; printers.json is left as it was."""
    first = registry.add(new("A", moonraker_url="http://10.0.0.5:7125"))
    other = registry.add(new("B"))
    before = registry.path.read_text()
    for spelling in ("http://10.0.0.5:7125", "HTTP://10.0.0.5:7125/", "10.0.0.5:7125"):
        with pytest.raises(InvalidInput, match="already uses") as refused:
            registry.add(new("C", moonraker_url=spelling))
        reason = refused.value.reasons[0]
        assert reason["code"] == "url_taken"
        assert first.id in reason["en"]
        assert "ya usa" in reason["es"]
        with pytest.raises(InvalidInput, match="already uses"):
            registry.update(other.id, PrinterUpdate(moonraker_url=spelling))
    assert registry.path.read_text() == before
    # Another port of the same host is another Moonraker (several printers on one Pi).
    registry.add(new("D", moonraker_url="http://10.0.0.5:7126"))
    # Editing a printer without moving it is not a conflict with itself.
    registry.update(first.id, PrinterUpdate(name="A2", moonraker_url="http://10.0.0.5:7125/"))


def test_a_hand_written_file_sharing_a_moonraker_stays_editable(path: Path) -> None:
    """printers.json written by hand may list one Moonraker twice: it loads, and its printers
    can still be edited; only moving a printer onto a taken Moonraker is refused."""
    shared = "http://10.0.0.7:7125"
    write_printers(
        path,
        [
            PrinterConfig(id="a", name="A", moonraker_url=shared),
            PrinterConfig(id="b", name="B", moonraker_url=shared),
            PrinterConfig(id="c", name="C", moonraker_url="http://10.0.0.8:7125"),
        ],
    )
    registry = PrinterRegistry(path)
    registry.reload()
    assert registry.update("b", PrinterUpdate(location="Room 2")).location == "Room 2"
    with pytest.raises(InvalidInput, match="already uses"):
        registry.update("c", PrinterUpdate(moonraker_url=shared))
