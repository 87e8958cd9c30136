"""A printer's webcams, proxied: ``GET /api/printers/{id}/webcams`` lists them with
KyberCore's own snapshot and stream URLs, which relay the camera's JPEG and MJPEG. Browsers
never need a route to the printers' network, and KyberCore's access rules apply.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path
from fastapi.responses import Response, StreamingResponse
from pydantic import BaseModel, Field
from starlette.types import Receive, Scope, Send

from kybercore.api.deps import VIEWER, Service
from kybercore.api.models import ERROR_RESPONSES
from kybercore.fleet.webcams import CameraStream

router = APIRouter(prefix="/api/printers")

CameraName = Annotated[str, Path(max_length=100, description="The webcam's name in Moonraker.")]
# A snapshot is "now": no cache may serve an old picture of a print.
_NO_STORE = {"Cache-Control": "no-store"}


class WebcamOut(BaseModel):
    """One enabled webcam, with the URLs a browser loads through KyberCore."""

    name: str
    snapshot_url: str = Field(description="A JPEG, now (relayed from the camera).")
    stream_url: str = Field(description="The MJPEG stream (relayed from the camera).")
    flip_horizontal: bool
    flip_vertical: bool
    rotation: int = Field(description="0, 90, 180 or 270 degrees.")
    aspect_ratio: str = Field(description='As Moonraker has it, e.g. "4:3".')


@router.get(
    "/{printer_id}/webcams",
    response_model=list[WebcamOut],
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def webcams(service: Service, printer_id: str) -> list[WebcamOut]:
    """The printer's enabled webcams, from Moonraker's ``/server/webcams/list``."""
    base = f"/api/printers/{printer_id}/webcams"
    return [
        WebcamOut(
            name=cam.name,
            snapshot_url=f"{base}/{cam.name}/snapshot",
            stream_url=f"{base}/{cam.name}/stream",
            flip_horizontal=cam.flip_horizontal,
            flip_vertical=cam.flip_vertical,
            rotation=cam.rotation,
            aspect_ratio=cam.aspect_ratio,
        )
        for cam in await service.cameras(printer_id)
    ]


@router.get(
    "/{printer_id}/webcams/{name}/snapshot",
    responses={**ERROR_RESPONSES, 200: {"content": {"image/jpeg": {}}}},
    response_class=Response,
    dependencies=[VIEWER],
)
async def snapshot(service: Service, printer_id: str, name: CameraName) -> Response:
    """One JPEG from the webcam."""
    image = await service.camera_snapshot(printer_id, name)
    return Response(image.content, media_type=image.media_type, headers=_NO_STORE)


@router.get(
    "/{printer_id}/webcams/{name}/stream",
    responses={**ERROR_RESPONSES, 200: {"content": {"multipart/x-mixed-replace": {}}}},
    response_class=StreamingResponse,
    dependencies=[VIEWER],
)
async def stream(service: Service, printer_id: str, name: CameraName) -> StreamingResponse:
    """The webcam's MJPEG stream, relayed until the browser goes away."""
    return _Relay(await service.camera_stream(printer_id, name))


class _Relay(StreamingResponse):
    """A camera's stream to the browser, closed however the response ends: when the
    browser leaves, and also when it left before the first byte (the body is then never
    read, so closing it in its own ``finally`` would never happen)."""

    def __init__(self, stream: CameraStream) -> None:
        super().__init__(stream, media_type=stream.content_type, headers=_NO_STORE)
        self._stream = stream

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            await self._stream.aclose()
