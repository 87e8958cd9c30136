"""`kybercore printers list|add|edit|remove`, driven through Typer's CliRunner."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import Result
from typer.testing import CliRunner

from kybercore.cli.printers import printers_app
from kybercore.registry.store import read_printers

SECRET = "cli-s3cr3t-0123456789abcdef"


@pytest.fixture
def path(tmp_path: Path) -> Path:
    return tmp_path / "printers.json"


def run(path: Path, *args: str, stdin: str | None = None, columns: int = 200) -> Result:
    """Run the sub-app as `kybercore printers --printers-file PATH ARGS...` (not a terminal)."""
    result = CliRunner().invoke(
        printers_app,
        ["--printers-file", str(path), *args],
        input=stdin,
        env={"COLUMNS": str(columns)},
    )
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


def add_two(path: Path) -> None:
    assert run(path, "add", "Ender 3", "--url", "http://10.0.0.5:7125/").exit_code == 0
    result = run(
        path,
        "add",
        "Voron",
        "--id",
        "voron",
        "--url",
        "https://voron.lan",
        "--model",
        "Voron 2.4",
        "--location",
        "Sala B",
        "--tag",
        "abs",
        "--tag",
        "big",
        "--api-key",
        SECRET,
        "--disabled",
        "--size",
        "350",
        "350",
        "340",
        "--nozzle",
        "0.4",
        "--material",
        "ABS",
        "--max-extruder-temp",
        "300",
        "--max-bed-temp",
        "120",
    )
    assert result.exit_code == 0, result.output
    assert "Added printer 'voron'" in result.stdout


def test_add_stores_every_option(path: Path) -> None:
    add_two(path)
    ender, voron = read_printers(path)
    assert ender.id == "ender-3"
    assert ender.moonraker_url == "http://10.0.0.5:7125"
    assert ender.enabled
    assert voron.model == "Voron 2.4"
    assert voron.location == "Sala B"
    assert voron.tags == ["abs", "big"]
    assert voron.api_key is not None
    assert voron.api_key.get_secret_value() == SECRET
    assert not voron.enabled
    caps = voron.capabilities
    assert caps.build_volume is not None
    assert (caps.build_volume.x, caps.build_volume.y, caps.build_volume.z) == (350, 350, 340)
    assert (caps.nozzle_diameter, caps.material) == (0.4, "ABS")
    assert (caps.max_extruder_temp, caps.max_bed_temp) == (300, 120)


def test_list_table_never_shows_the_key(path: Path) -> None:
    add_two(path)
    result = run(path, "list")
    assert result.exit_code == 0
    assert SECRET not in result.output
    for text in ("ender-3", "Voron 2.4", "Sala B", "https://voron.lan", "not set"):
        assert text in result.stdout
    voron_row = next(line for line in result.stdout.splitlines() if "voron.lan" in line)
    assert " no " in voron_row
    assert " set " in voron_row


def test_a_piped_list_is_never_cut_whatever_the_width(path: Path) -> None:
    url = "http://printer-with-a-long-name.farm.example.com:7125"
    assert run(path, "add", "Long", "--url", url, "--location", "Sala B").exit_code == 0
    result = run(path, "list", columns=40)
    assert result.exit_code == 0
    assert url in result.stdout
    assert "…" not in result.stdout


def test_list_json_is_the_public_view(path: Path) -> None:
    add_two(path)
    result = run(path, "list", "--json")
    assert result.exit_code == 0
    assert SECRET not in result.output
    printers = json.loads(result.stdout)
    assert [p["id"] for p in printers] == ["ender-3", "voron"]
    assert [p["api_key_set"] for p in printers] == [False, True]
    assert all("api_key" not in p for p in printers)


def test_list_empty_and_envvar(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("KYBERCORE_PRINTERS", str(path))
    result = CliRunner().invoke(printers_app, ["list"])
    assert result.exit_code == 0
    assert "No printers in" in result.stdout
    assert CliRunner().invoke(printers_app, ["add", "A", "--url", "http://a"]).exit_code == 0
    assert [p.id for p in read_printers(path)] == ["a"]


def test_edit_changes_only_what_is_given(path: Path) -> None:
    add_two(path)
    result = run(path, "edit", "voron", "--name", "Voron Trident", "--enable", "--nozzle", "0.6")
    assert result.exit_code == 0, result.output
    voron = read_printers(path)[1]
    assert voron.name == "Voron Trident"
    assert voron.enabled
    assert voron.capabilities.nozzle_diameter == 0.6
    assert voron.capabilities.material == "ABS"  # kept
    assert voron.location == "Sala B"  # kept
    assert voron.api_key is not None  # kept
    assert voron.site == ""
    assert run(path, "edit", "voron", "--site", "lab-b").exit_code == 0
    assert read_printers(path)[1].site == "lab-b"


def test_edit_api_key_set_and_clear(path: Path) -> None:
    add_two(path)
    assert run(path, "edit", "ender-3", "--api-key", "new-key").exit_code == 0
    key = read_printers(path)[0].api_key
    assert key is not None
    assert key.get_secret_value() == "new-key"
    assert run(path, "edit", "ender-3", "--clear-api-key").exit_code == 0
    assert read_printers(path)[0].api_key is None


def test_remove_asks_first(path: Path) -> None:
    add_two(path)
    declined = run(path, "remove", "voron", stdin="n\n")
    assert declined.exit_code == 1
    assert "Nothing removed" in declined.stdout
    assert len(read_printers(path)) == 2
    accepted = run(path, "remove", "voron", stdin="y\n")
    assert accepted.exit_code == 0
    assert [p.id for p in read_printers(path)] == ["ender-3"]
    assert run(path, "remove", "ender-3", "--yes").exit_code == 0
    assert read_printers(path) == []


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["add", "X", "--url", "ftp://x"], 2, "--url: the URL must start with http://"),
        (["add", "X", "--url", "http://u:p@x"], 2, "--url: the URL must not contain credentials"),
        (["add", "X", "--id", "Bad Id", "--url", "http://x"], 2, "--id: String should match"),
        (["add", "X", "--url", "http://x", "--id", "ender-3"], 2, "id 'ender-3' already exists"),
        (["add", "X", "--url", "http://x", "--size", "0", "1", "1"], 2, "--size: Input should"),
        (["add", "X", "--url", "http://x", "--nozzle", "-1"], 2, "--nozzle: Input should"),
        (["edit", "ender-3", "--site", "Lab B"], 2, "--site: String should match"),
        (["edit", "nope", "--name", "Z"], 1, "No printer with id 'nope'"),
        (["edit", "ender-3"], 2, "Nothing to change"),
        (["edit", "ender-3", "--api-key", "k", "--clear-api-key"], 2, "not both"),
        (["edit", "ender-3", "--name", " "], 2, "NAME / --name: String should have at least"),
        (["remove", "nope", "--yes"], 1, "No printer with id 'nope'"),
    ],
)
def test_errors_are_one_red_line(path: Path, args: list[str], code: int, message: str) -> None:
    add_two(path)
    before = path.read_bytes()
    result = run(path, *args)
    assert result.exit_code == code
    assert result.stderr.startswith("Error: ")
    assert message in result.stderr
    assert result.stderr.count("\n") == 1
    assert path.read_bytes() == before


def test_broken_file_reported_with_line_and_left_alone(path: Path) -> None:
    add_two(path)
    broken = path.read_text().replace('"version": 1,', '"version": 1')
    path.write_text(broken)
    for args in (["list"], ["add", "X", "--url", "http://x"], ["remove", "voron", "--yes"]):
        result = run(path, *args)
        assert result.exit_code == 1
        assert f"Error: {path}, line 3, column 3: not valid JSON" in result.stderr
    assert path.read_text() == broken


def test_unwritable_folder_is_an_error_not_a_traceback(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    result = run(blocker / "printers.json", "add", "X", "--url", "http://x")
    assert result.exit_code == 1
    assert "cannot be written" in result.stderr
