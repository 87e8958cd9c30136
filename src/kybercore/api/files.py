"""``/api/printers/{printer_id}/files``: a printer's G-code files, their metadata and
thumbnails, uploads and deletes.

Every path a client names goes through :func:`~kybercore.core.paths.safe_path` first: it
is relative to the printer's ``gcodes/`` root and must stay there.
"""

from __future__ import annotations

from typing import Annotated, Any, Final

from fastapi import APIRouter, File, Form, Request, UploadFile
from fastapi.responses import Response

from kybercore.api.deps import OPERATOR, VIEWER, Service
from kybercore.api.models import (
    ERROR_RESPONSES,
    FileItem,
    FilePath,
    UploadResult,
    upload_result,
)
from kybercore.api.recorder import note
from kybercore.core.paths import safe_path
from kybercore.errors import InvalidInput

router = APIRouter(prefix="/api/printers/{printer_id}/files")


@router.get(
    "",
    response_model=list[FileItem],
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def files(service: Service, printer_id: str) -> list[dict[str, Any]]:
    """The printer's G-code files, newest first."""
    return await service.files(printer_id)


@router.delete(
    "",
    status_code=204,
    responses=ERROR_RESPONSES,
    dependencies=[OPERATOR],
)
async def delete_file(service: Service, printer_id: str, path: FilePath) -> Response:
    """Delete a G-code file (refused while it is being printed)."""
    await service.delete_file(printer_id, safe_path(path))
    return Response(status_code=204)


@router.get("/metadata", responses=ERROR_RESPONSES, dependencies=[VIEWER])
async def file_metadata(service: Service, printer_id: str, filename: FilePath) -> dict[str, Any]:
    """What the slicer wrote in a file's header, as Moonraker parsed it."""
    return await service.file_metadata(printer_id, safe_path(filename))


_IMAGE: Final = {"schema": {"type": "string", "format": "binary"}}


@router.get(
    "/thumbnail",
    response_class=Response,
    responses={
        200: {"description": "The image.", "content": {"image/png": _IMAGE, "image/jpeg": _IMAGE}},
        **ERROR_RESPONSES,
    },
    dependencies=[VIEWER],
)
async def thumbnail(service: Service, printer_id: str, path: FilePath) -> Response:
    """A thumbnail image (path as given by a file's metadata, relative to gcodes/)."""
    path = safe_path(path)
    if not path.lower().endswith((".png", ".jpg", ".jpeg")):
        raise InvalidInput("Only .png and .jpg thumbnails can be fetched.")
    image = await service.thumbnail(printer_id, path)
    # private: it may be behind a token, so no shared cache (a proxy) may keep it.
    headers = {"Cache-Control": "private, max-age=300"}
    return Response(image.content, media_type=image.media_type, headers=headers)


@router.post(
    "",
    status_code=201,
    response_model=UploadResult,
    responses=ERROR_RESPONSES,
    dependencies=[OPERATOR],
)
async def upload(
    request: Request,
    service: Service,
    printer_id: str,
    file: Annotated[UploadFile, File(description="The G-code file.")],
    start: Annotated[bool, Form(description="Print it right after the upload.")] = False,
    confirm: Annotated[bool, Form(description="Go ahead despite warnings.")] = False,
) -> dict[str, Any]:
    """Upload a G-code file (checksummed); optionally validate it and start printing.

    201 once the file is stored, whatever became of the start (``started``, ``start``): a
    start refused then is reported with its reasons, never as a failed upload. An error
    answer is the upload's own failure (or a start refused before any byte was sent)."""
    note(request, params={"file": file.filename, "start": start, "confirm": confirm})
    filename = safe_path(file.filename or "")
    # The body was counted as it arrived (GuardMiddleware, the upload limit); the file
    # itself stays spooled on disk and is streamed on to Moonraker.
    outcome = await service.upload(printer_id, filename, file.file, start=start, confirm=confirm)
    return upload_result(outcome)
