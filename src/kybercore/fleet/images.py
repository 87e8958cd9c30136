"""Images a printer serves, as the API answers them: a G-code file's thumbnail, a webcam's
snapshot. Bytes and their media type travel together (a front gets them from a worker)."""

from __future__ import annotations

import mimetypes
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Image:
    """An image's bytes and its media type (``image/png``, ``image/jpeg``)."""

    content: bytes
    media_type: str


def media_type_of(path: str) -> str:
    """The media type a file's name says (``application/octet-stream`` when it says none)."""
    return mimetypes.guess_type(path)[0] or "application/octet-stream"
