"""Finding Mainsail or Fluidd on a printer's host: the page's title decides."""

from __future__ import annotations

import pytest

from kybercore.fleet.web_ui import kind_of, root_of


@pytest.mark.parametrize(
    ("page", "kind"),
    [
        (b"<!doctype html><html><head><title>Mainsail</title>", "mainsail"),
        (b"<html><head><TITLE lang=en>Voron 2.4 | mainsail</TITLE>", "mainsail"),
        (b"<html><head><title>Fluidd</title></head>", "fluidd"),
        (b"<html><head><title>Welcome to nginx!</title>", None),
        (b"<html><body>Mainsail is mentioned, but not in a title", None),
        (b"", None),
    ],
)
def test_the_title_names_the_interface(page: bytes, kind: str | None) -> None:
    assert kind_of(page) == kind


@pytest.mark.parametrize(
    ("moonraker", "root"),
    [
        ("http://192.168.1.50:7125", "http://192.168.1.50/"),
        ("https://printer.local", "https://printer.local/"),
        ("http://[fd00::5]:7125", "http://[fd00::5]/"),
    ],
)
def test_the_interface_is_looked_for_at_the_hosts_root(moonraker: str, root: str) -> None:
    assert root_of(moonraker) == root
