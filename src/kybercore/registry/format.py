"""The printers.json format, ``{"version": 1, "printers": [...]}``: parse and dump, no I/O.

A file that does not parse or validate gives a :class:`ConfigError` naming the file, the
line and column, the printer (index and id), the field and the reason, and what to do.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Final

from pydantic import ValidationError

from kybercore.errors import ConfigError
from kybercore.registry.models import PrinterConfig

FORMAT_VERSION: Final = 1
_SHAPE = f'"version": {FORMAT_VERSION}, "printers": [...]'


def backup_path(path: Path) -> Path:
    """Where the previous version of ``path`` is kept: ``printers.json.bak``."""
    return path.with_name(path.name + ".bak")


def dump_printers(printers: list[PrinterConfig]) -> bytes:
    """The file's bytes: indented JSON, fields in model order, API keys included."""
    body = {"version": FORMAT_VERSION, "printers": [p.to_file_dict() for p in printers]}
    return (json.dumps(body, indent=2, ensure_ascii=False) + "\n").encode()


def parse_printers(text: str, path: Path) -> list[PrinterConfig]:
    """Parse and validate the text of a printers.json; ``path`` is only used in messages."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(
            f"{path}, line {exc.lineno}, column {exc.colno}: not valid JSON ({exc.msg}); "
            f"the file may be half-written or mis-edited. {_what_to_do(path)}"
        ) from None
    if not isinstance(data, dict):
        raise _problem(path, text, (), f"expected {{{_SHAPE}}}")
    if data.get("version") != FORMAT_VERSION:
        raise _problem(
            path,
            text,
            ("version",),
            f"unsupported or missing version {data.get('version')!r}; "
            f"this KyberCore reads version {FORMAT_VERSION}",
        )
    unexpected = sorted(data.keys() - {"version", "printers"})
    if unexpected:
        key = unexpected[0]
        raise _problem(path, text, (key,), f"unexpected key {key!r}; expected {{{_SHAPE}}}")
    if not isinstance(data.get("printers"), list):
        raise _problem(path, text, ("printers",), "'printers' must be a list")
    printers: list[PrinterConfig] = []
    for index, item in enumerate(data["printers"]):
        try:
            printers.append(PrinterConfig.model_validate(item))
        except ValidationError as exc:
            raise _invalid_printer(path, text, index, item, exc) from None
    seen: set[str] = set()
    for index, printer in enumerate(printers):
        if printer.id in seen:
            reason = f"printers[{index}]: id {printer.id!r} is used by an earlier printer"
            raise _problem(path, text, ("printers", index, "id"), reason)
        seen.add(printer.id)
    return printers


def _invalid_printer(
    path: Path, text: str, index: int, item: object, exc: ValidationError
) -> ConfigError:
    errors = exc.errors(include_input=False)  # never echo an api_key
    first = errors[0]
    printer_id = item.get("id") if isinstance(item, dict) else None
    who = f"printers[{index}]" + (f" (id {printer_id!r})" if isinstance(printer_id, str) else "")
    field = ".".join(str(part) for part in first["loc"])
    reason = str(first["ctx"]["error"]) if first["type"] == "value_error" else first["msg"]
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    where = ("printers", index, *first["loc"])
    return _problem(path, text, where, f"{who}, field '{field}': {reason}{more}")


def _problem(path: Path, text: str, where: tuple[str | int, ...], reason: str) -> ConfigError:
    """A ConfigError pointing at the line and column of ``where`` in the file."""
    offset = _offset_of(text, where)
    line = text.count("\n", 0, offset) + 1
    column = offset - text.rfind("\n", 0, offset)
    return ConfigError(f"{path}, line {line}, column {column}: {reason}. {_what_to_do(path)}")


def _what_to_do(path: Path) -> str:
    bak = backup_path(path)
    return f"Fix the file, or restore {bak}; KyberCore will not write to it until it is valid."


def _offset_of(text: str, where: tuple[str | int, ...]) -> int:
    """Offset in ``text`` (valid JSON) of the value at ``where``.

    When ``where`` does not exist (a missing field), the offset of the deepest value found.
    The json module keeps no positions, so walk the text, skipping values with raw_decode.
    """
    decoder = json.JSONDecoder()

    def skip_space(i: int) -> int:
        while i < len(text) and text[i] in " \t\n\r":
            i += 1
        return i

    offset = skip_space(0)
    for step in where:
        opener = text[offset]
        if opener not in ("{", "["):
            break
        pos, index, found = skip_space(offset + 1), 0, None
        while text[pos] not in ("}", "]"):
            key: object = index
            if opener == "{":
                key, pos = decoder.raw_decode(text, pos)
                pos = skip_space(skip_space(pos) + 1)  # past the ':'
            if key == step:
                found = pos
                break
            pos = skip_space(decoder.raw_decode(text, pos)[1])
            if text[pos] == ",":
                pos = skip_space(pos + 1)
            index += 1
        if found is None:
            break
        offset = found
    return offset
