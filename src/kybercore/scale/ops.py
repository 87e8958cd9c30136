"""What a printer's owner runs for a front: one function per command ``op``, each calling
the worker's :class:`FleetService` as ``kybercore serve`` would and encoding the result for
the wire (:mod:`.wire`). The front's side of each is in :mod:`.front`.

A result must fit in one NATS message: images are refused above
:data:`~kybercore.scale.wire.MAX_IMAGE` with a clear error, and :mod:`.commands` answers any
other result that does not fit with one too.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any, Final

from kybercore.errors import shorten
from kybercore.fleet.service import FleetService
from kybercore.jobs.printers import FleetPrinters
from kybercore.scale.wire import (
    encode_image,
    encode_macros,
    encode_outcome,
    encode_verdict,
    encode_webcams,
)

Op = Callable[[FleetService, str, dict[str, Any]], Awaitable[Any]]
"""``(service, printer_id, args)``: the result, as plain data."""


async def _act(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    outcome = await service.act(
        printer_id, args["action"], args.get("params"),
        force=bool(args.get("force")), confirm=bool(args.get("confirm")),
    )  # fmt: skip
    return encode_outcome(outcome)


async def _dry_run(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    verdict = await service.dry_run(
        printer_id, args["action"], args.get("params"), bool(args.get("force"))
    )
    return encode_verdict(verdict)


async def _files(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    return await service.files(printer_id)


async def _file_metadata(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    return await service.file_metadata(printer_id, args["filename"])


async def _delete_file(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    await service.delete_file(printer_id, args["path"])


async def _console_history(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    return await service.console_history(printer_id, int(args["count"]))


async def _macros(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    return encode_macros(await service.macros(printer_id))


async def _exclude_object(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    return await service.exclude_object_status(printer_id)


async def _temperatures(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    return await service.temperatures(printer_id, float(args["minutes"]))


async def _thumbnail(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    path = str(args["path"])
    image = await service.thumbnail(printer_id, path)
    return encode_image(image, f"{printer_id}: the thumbnail '{shorten(path)}'")


async def _cameras(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    return encode_webcams(await service.cameras(printer_id))


async def _camera_snapshot(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    name = str(args["name"])
    image = await service.camera_snapshot(printer_id, name)
    return encode_image(image, f"{printer_id}: the snapshot of webcam '{shorten(name)}'")


# The job queue on a front (kybercore.scale.queue): what `kybercore serve`'s queue does
# through FleetPrinters, done by the owner with the same class over its own sessions.


async def _print_start(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    await FleetPrinters(service).start(printer_id, str(args["name"]))


async def _print_cancel(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    await FleetPrinters(service).cancel(printer_id)


async def _history_job(service: FleetService, printer_id: str, args: dict[str, Any]) -> Any:
    job_id = args.get("job_id")
    return await FleetPrinters(service).history_job(
        printer_id, str(args["upload_name"]), str(job_id) if job_id else None
    )


OPS: Final[dict[str, Op]] = {
    "act": _act,
    "dry_run": _dry_run,
    "files": _files,
    "file_metadata": _file_metadata,
    "delete_file": _delete_file,
    "console_history": _console_history,
    "macros": _macros,
    "exclude_object": _exclude_object,
    "temperatures": _temperatures,
    "thumbnail": _thumbnail,
    "cameras": _cameras,
    "camera_snapshot": _camera_snapshot,
    "print_start": _print_start,
    "print_cancel": _print_cancel,
    "history_job": _history_job,
}
"""Every command a worker takes, by ``op``."""
