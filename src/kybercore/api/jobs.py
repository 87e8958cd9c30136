"""The job queue over HTTP: ``/api/jobs``, ``/api/queue``, ``/api/gates`` and the plate
gate of each printer (``/api/printers/{id}/clear|hold|release``).

Viewers read; operators change. Every change the queue makes goes out on ``/ws`` as a
``{"type": "queue", ...}`` frame (:class:`~kybercore.jobs.service.QueueService` pushes
them), so dashboards follow without polling.

``POST /api/jobs`` takes either a multipart upload (the file plus the form fields of
:class:`JobUpload`) or JSON :class:`JobFromPrinter` (a file already on a printer): one
route, the body's content type says which. Uploads stream to disk under the same limit
as printer uploads (:class:`~kybercore.api.guard.GuardMiddleware`).
"""

from __future__ import annotations

from pathlib import PurePosixPath
from typing import Annotated, Any, Final, TypeVar

from fastapi import APIRouter, Path, Query, Request
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError
from starlette.datastructures import FormData, UploadFile

from kybercore.api.deps import VIEWER, Operator, Queue, Service
from kybercore.api.models import ERROR_RESPONSES
from kybercore.api.queue_models import (
    MAX_ID,
    UPLOAD_FORM_SCHEMA,
    AttemptOut,
    ClearRequest,
    GateOut,
    HoldRequest,
    JobFromPrinter,
    JobOut,
    JobPatch,
    JobUpload,
    MoveRequest,
    QueueChange,
    QueueState,
    WhyLineOut,
)
from kybercore.api.recorder import note
from kybercore.core.paths import safe_path
from kybercore.errors import InvalidInput
from kybercore.jobs.models import Job
from kybercore.jobs.service import QueueService

router = APIRouter()

JobId = Annotated[int, Path(ge=1, le=MAX_ID, description="The job's id.")]
M = TypeVar("M", JobUpload, JobFromPrinter)
_JSON: Final = "application/json"
_MULTIPART: Final = "multipart/form-data"
_CREATE_BODY: Final = {
    "requestBody": {
        "required": True,
        "content": {
            _MULTIPART: {"schema": UPLOAD_FORM_SCHEMA},
            _JSON: {"schema": JobFromPrinter.model_json_schema()},
        },
    }
}
_MAX_FORM_FIELDS: Final = 100
_GCODE_SUFFIXES: Final = (".gcode", ".g", ".gco")


@router.get(
    "/api/jobs", response_model=list[JobOut], responses=ERROR_RESPONSES, dependencies=[VIEWER]
)
async def list_jobs(
    queue: Queue,
    finished: Annotated[
        bool, Query(description="Include jobs that are done or cancelled.")
    ] = False,
) -> list[Job]:
    """The queue in dispatch order: priority (highest first), then position."""
    return await queue.jobs(include_finished=finished)


@router.post(
    "/api/jobs",
    status_code=201,
    response_model=JobOut,
    responses={**ERROR_RESPONSES, 413: {"description": "The upload is too large."}},
    openapi_extra=_CREATE_BODY,
)
async def create_job(request: Request, queue: Queue, user: Operator) -> Job:
    """Queue a job: upload its file (multipart: ``file`` plus the fields of
    JobUploadForm), or name a file already on a printer (JSON: JobFromPrinter).

    Refused with 422 and the reasons per printer when no printer of the fleet could ever
    print it (wrong material everywhere, too tall for every printer…)."""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind == _JSON:
        source = _validated(JobFromPrinter, await request.body())
        return await queue.add_job_from_printer(
            source.printer,
            safe_path(source.path),
            **source.job_fields(source.printer if source.pin else None),
            user=user.name,
        )
    if kind != _MULTIPART:
        raise InvalidInput(
            "Send the job as multipart/form-data (a 'file' and its options) or as JSON "
            '{"printer": ..., "path": ...} for a file already on a printer.'
        )
    async with request.form(max_files=1, max_fields=_MAX_FORM_FIELDS) as form:
        upload, options = _upload_form(form)
        fields = options.model_dump(mode="json", exclude_defaults=True)
        note(request, params={"file": upload.filename, **fields})  # the audit log reads no form
        return await queue.add_job(
            _job_file_name(upload.filename or ""),
            upload.file,
            **options.job_fields(options.printer),
            user=user.name,
        )


@router.get(
    "/api/jobs/{job_id}", response_model=JobOut, responses=ERROR_RESPONSES, dependencies=[VIEWER]
)
async def get_job(queue: Queue, job_id: JobId) -> Job:
    """One job and its counters."""
    return await queue.job(job_id)


@router.patch("/api/jobs/{job_id}", response_model=JobOut, responses=ERROR_RESPONSES)
async def edit_job(queue: Queue, user: Operator, job_id: JobId, patch: JobPatch) -> Job:
    """Change a job's priority, quantity, start time or attempts (omitted: unchanged)."""
    changes = patch.model_dump(include=patch.model_fields_set)
    return await queue.update_job(job_id, **changes, user=user.name)


@router.delete("/api/jobs/{job_id}", response_model=JobOut, responses=ERROR_RESPONSES)
async def cancel_job(
    queue: Queue,
    user: Operator,
    job_id: JobId,
    confirm: Annotated[
        bool, Query(description="Also cancel the copies printing now (the 409 lists them).")
    ] = False,
) -> Job:
    """Cancel a job. With copies printing, 409 ``confirmation_required`` lists them until
    asked again with ``?confirm=true``, which cancels those prints too."""
    return await queue.cancel_job(job_id, user=user.name, confirm=confirm)


@router.post("/api/jobs/{job_id}/move", response_model=JobOut, responses=ERROR_RESPONSES)
async def move_job(queue: Queue, user: Operator, job_id: JobId, move: MoveRequest) -> Job:
    """Reorder: put the job just before another one, or last."""
    return await queue.move_job(job_id, move.before, user=user.name)


@router.post("/api/jobs/{job_id}/requeue", response_model=JobOut, responses=ERROR_RESPONSES)
async def requeue_job(queue: Queue, user: Operator, job_id: JobId) -> Job:
    """Put a blocked job back in the queue, its failure count reset."""
    return await queue.requeue_job(job_id, user=user.name)


@router.get(
    "/api/jobs/{job_id}/why",
    response_model=list[WhyLineOut],
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def why(queue: Queue, job_id: JobId) -> list[Any]:
    """Why the job is not running on each printer right now (empty: nothing holds it)."""
    return await queue.why(job_id)


@router.get(
    "/api/jobs/{job_id}/attempts",
    response_model=list[AttemptOut],
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def attempts(queue: Queue, job_id: JobId) -> list[Any]:
    """Every attempt at the job's copies, oldest first."""
    await queue.job(job_id)  # an unknown job is a 404, not an empty list
    return await queue.attempts(job_id)


@router.get("/api/queue", response_model=QueueState, dependencies=[VIEWER])
async def queue_state(queue: Queue) -> QueueState:
    """Paused or not, jobs and copies to go, printers awaiting a clear or held."""
    return await _state(queue)


@router.post("/api/queue", response_model=QueueState, responses=ERROR_RESPONSES)
async def change_queue(
    request: Request, queue: Queue, user: Operator, change: QueueChange
) -> QueueState:
    """Pause (no new copy starts; prints under way go on) or resume dispatching."""
    note(request, action="queue.pause" if change.paused else "queue.resume")
    if change.paused:
        await queue.pause(user=user.name)
    else:
        await queue.resume(user=user.name)
    return await _state(queue)


@router.get("/api/gates", response_model=dict[str, GateOut], dependencies=[VIEWER])
async def gates(queue: Queue) -> dict[str, Any]:
    """Every printer's plate gate, by printer id."""
    return dict(await queue.gates())


@router.post("/api/printers/{printer_id}/clear", response_model=GateOut, responses=ERROR_RESPONSES)
async def clear(
    queue: Queue, service: Service, user: Operator, printer_id: str, body: ClearRequest
) -> Any:
    """Clear the plate of a printer awaiting it: ``good`` counts the copy done, ``bad``
    sends it back to the queue. The printer is available again."""
    service.config(printer_id)  # an unknown printer is a 404
    return await queue.clear(printer_id, body.verdict, cause=body.cause, user=user.name)


@router.post("/api/printers/{printer_id}/hold", response_model=GateOut, responses=ERROR_RESPONSES)
async def hold(
    queue: Queue, service: Service, user: Operator, printer_id: str, body: HoldRequest
) -> Any:
    """Keep the queue off a printer (a print under way goes on) until it is released."""
    service.config(printer_id)
    return await queue.hold(printer_id, body.reason, user=user.name)


@router.post(
    "/api/printers/{printer_id}/release", response_model=GateOut, responses=ERROR_RESPONSES
)
async def release(queue: Queue, service: Service, user: Operator, printer_id: str) -> Any:
    """Give a held printer back to the queue."""
    service.config(printer_id)
    return await queue.release(printer_id, user=user.name)


# -- helpers ------------------------------------------------------------------------------


def _validated(model: type[M], data: bytes | dict[str, Any]) -> M:
    """``data`` as ``model``; a refusal names each field as any invalid request does."""
    try:
        if isinstance(data, bytes):
            return model.model_validate_json(data)
        return model.model_validate(data)
    except ValidationError as exc:
        raise RequestValidationError(exc.errors(include_input=False)) from None


def _upload_form(form: FormData) -> tuple[UploadFile, JobUpload]:
    """The uploaded file and the job's options from a multipart form."""
    upload = form.get("file")
    if not isinstance(upload, UploadFile):
        raise InvalidInput("No file: send the G-code as the form field 'file'.")
    fields: dict[str, Any] = {}
    for name in form:
        if name == "file":
            continue
        values = [v for v in form.getlist(name) if isinstance(v, str) and v != ""]
        if name == "tags":
            fields[name] = values
        elif values:
            # A blank field (a form's empty input) means "not given".
            fields[name] = values[-1]
    return upload, _validated(JobUpload, fields)


def _job_file_name(filename: str) -> str:
    """The uploaded file's own name (no folders), if it is a G-code file name."""
    name = PurePosixPath(safe_path(filename).replace("\\", "/")).name
    if not name.lower().endswith(_GCODE_SUFFIXES):
        raise InvalidInput(
            f"'{name}' is not a G-code file: the name must end in .gcode, .g or .gco."
        )
    return name


async def _state(queue: QueueService) -> QueueState:
    jobs = await queue.jobs(include_finished=False)
    gates = await queue.gates()
    return QueueState(
        paused=await queue.paused(),
        queued=sum(job.state == "queued" for job in jobs),
        blocked=sum(job.state == "blocked" for job in jobs),
        copies_left=sum(job.left for job in jobs if job.state == "queued"),
        copies_in_flight=sum(job.in_flight for job in jobs),
        copies_printing=sum(job.in_flight - job.awaiting_clear for job in jobs),
        awaiting_clear=sorted(p for p, g in gates.items() if g.state == "awaiting_clear"),
        held=sorted(p for p, g in gates.items() if g.state in ("held", "maintenance")),
    )
