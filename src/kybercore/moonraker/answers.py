"""The shapes KyberCore expects in Moonraker's answers; anything else is a typed error.

A real Moonraker answers with the documented shapes. A broken proxy, another server on the
port or a future version may not, and ``dict()``/``list()`` would take some wrong shapes
without a word (a list of pairs, the keys of a dict): every answer the client hands on is
checked here first, so callers get the type they were promised or a
:class:`MoonrakerRpcError` naming the request.
"""

from __future__ import annotations

from typing import Any, Final

from kybercore.errors import MoonrakerRpcError
from kybercore.moonraker.objects import Status, snapshot_status

MALFORMED: Final = -32603
"""JSON-RPC's "internal error", the code every unexpected answer is reported with."""


def malformed(what: str, why: str, where: str, printer: str) -> MoonrakerRpcError:
    """The error for an answer to ``what`` that is not what Moonraker sends."""
    return MoonrakerRpcError(
        MALFORMED,
        f"unexpected answer to '{what}' ({why}). Is {where} really Moonraker?",
        printer=printer,
    )


class Shapes:
    """Checks one printer's answers (``where``: its URL, for the message)."""

    def __init__(self, where: str, printer: str) -> None:
        self._where = where
        self._printer = printer

    def object(self, value: Any, what: str) -> dict[str, Any]:
        """``value``, which must be a JSON object."""
        if not isinstance(value, dict):
            raise self._bad(what, f"{_kind(value)} where an object belongs")
        return value

    def field(self, value: Any, key: str, what: str) -> Any:
        """``value[key]``; ``value`` must be an object that has it."""
        found = self.object(value, what)
        if key not in found:
            raise self._bad(what, f"no '{key}'")
        return found[key]

    def objects(self, value: Any, what: str) -> list[dict[str, Any]]:
        """``value``, which must be a list of objects."""
        if not isinstance(value, list) or not all(isinstance(item, dict) for item in value):
            raise self._bad(what, f"{_kind(value)} where a list of objects belongs")
        return value

    def names(self, value: Any, what: str) -> list[str]:
        """``value``, which must be a list of strings."""
        if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
            raise self._bad(what, f"{_kind(value)} where a list of names belongs")
        return value

    def status(self, value: Any, what: str) -> Status:
        """The printer objects of a query or subscription answer (``{"status": {...}}``);
        an object that is not an object is dropped, as in every status update."""
        status = snapshot_status(value)
        if status is None:
            raise self._bad(what, "no 'status' object")
        return status

    def _bad(self, what: str, why: str) -> MoonrakerRpcError:
        return malformed(what, why, self._where, self._printer)


def _kind(value: Any) -> str:
    """``value``'s JSON type, in words."""
    if value is None:
        return "null"
    names = {bool: "a boolean", str: "a string", list: "a list", dict: "an object"}
    return names.get(type(value), "a number" if isinstance(value, (int, float)) else "a value")
