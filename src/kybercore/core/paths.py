"""File names that clients give: always relative to the printer's gcodes/ folder."""

from __future__ import annotations

from kybercore.errors import InvalidInput, shorten

MAX_PATH: int = 1024

# One part of a path: anything but "." and "..", without a separator or control character.
_PART = r"[^\x00-\x1f/\\.][^\x00-\x1f/\\]*|\.[^\x00-\x1f/\\.][^\x00-\x1f/\\]*|\.\.[^\x00-\x1f/\\]+"
SAFE_PATH_PATTERN: str = rf"^(?:{_PART})(?:[/\\](?:{_PART}))*$"
"""What :func:`safe_path` accepts (with at most ``MAX_PATH`` characters), as a regular
expression for the OpenAPI schema: generated clients and fuzzers see the real rule."""


def safe_path(path: str) -> str:
    """``path`` when it is a file path relative to gcodes/; :class:`InvalidInput` otherwise.

    No absolute paths, no ``..`` or empty parts, no control characters: a name never
    reaches another folder of the printer (its config, its logs).
    """
    parts = path.replace("\\", "/").split("/")
    if (
        not path
        or len(path) > MAX_PATH
        or path.startswith("/")
        or any(p in ("", ".", "..") for p in parts)
        or any(ord(c) < 32 for c in path)
    ):
        raise InvalidInput(
            f"'{shorten(path)}' is not a valid file name: use a relative path without '..'."
        )
    return path
