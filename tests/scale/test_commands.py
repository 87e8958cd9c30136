"""A worker's side of a command, without a broker: the op runs on the FleetService, and an
answer too large for one NATS message is answered with a clear error instead (else the front
would wait for it in vain)."""

from __future__ import annotations

import time
from typing import Any

from nats.errors import MaxPayloadError

from kybercore.api.errors import error_status
from kybercore.errors import ActionRejected, KyberCoreError, MoonrakerRpcError
from kybercore.fleet.images import Image
from kybercore.scale.commands import CommandRunner
from kybercore.scale.wire import MAX_IMAGE, decode_error, decode_image, dumps, loads
from tests.helpers import wait_for

NATS_MAX_PAYLOAD = 1024 * 1024
"""nats-server's default max_payload."""


class FakeMsg:
    """Fake: a command as nats-py delivers it; refuses what NATS refuses (max_payload)."""

    def __init__(self, printer_id: str, op: str, **args: Any) -> None:
        self.subject = f"kc.cmd.{printer_id}"
        request = {"id": f"{op}-{time.time()}", "op": op, "args": args}
        self.data = dumps({**request, "deadline": time.time() + 30})
        self.headers = {"KC-Epoch": "1"}
        self.answers: list[dict[str, Any]] = []

    async def respond(self, data: bytes) -> None:
        if len(data) > NATS_MAX_PAYLOAD:
            raise MaxPayloadError
        self.answers.append(loads(data))


class FakeService:
    """Fake: the FleetService calls the ops make, with answers of a chosen size."""

    def __init__(self, files: int = 3, image: int = 100) -> None:
        self._files = files
        self._image = image
        self.moonraker = FakeClient()

    def client(self, printer_id: str) -> FakeClient:
        return self.moonraker

    async def files(self, printer_id: str) -> list[dict[str, Any]]:
        return [{"path": f"part-{i:06d}.gcode", "size": i} for i in range(self._files)]

    async def thumbnail(self, printer_id: str, path: str) -> Image:
        return Image(b"\x89PNG" + b"\0" * (self._image - 4), "image/png")


class FakeClient:
    """Fake: the Moonraker calls of the queue's ops, recorded; a history of two jobs."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, ...]] = []
        self.jobs = [{"job_id": "000002", "filename": "b.gcode"}, {"job_id": "000001",
                     "filename": "a.gcode"}]  # fmt: skip

    async def print_start(self, name: str) -> None:
        self.calls.append(("print_start", name))

    async def print_cancel(self) -> None:
        self.calls.append(("print_cancel",))

    async def history_job(self, job_id: str) -> dict[str, Any]:
        found = [job for job in self.jobs if job["job_id"] == job_id]
        if not found:
            raise MoonrakerRpcError(404, f"job {job_id} not found", printer="p1")
        return found[0]

    async def history_list(self, limit: int) -> dict[str, Any]:
        return {"count": len(self.jobs), "jobs": self.jobs[:limit]}


async def run(service: FakeService, op: str, **args: Any) -> dict[str, Any]:
    """The final answer the worker gives to one command (after its acknowledgement)."""
    runner = CommandRunner(service, lambda _printer: 1)  # type: ignore[arg-type]
    msg = FakeMsg("p1", op, **args)
    await runner.on_message(msg)  # type: ignore[arg-type]
    await wait_for(lambda: len(msg.answers) == 2, timeout=10, what="the command's answer")
    assert msg.answers[0] == {"ack": True}
    return msg.answers[1]


async def test_ops_run_on_the_service_and_answer_plain_data() -> None:
    assert len((await run(FakeService(files=3), "files"))["ok"]) == 3
    answer = await run(FakeService(image=MAX_IMAGE), "thumbnail", path=".thumbs/a.png")
    image = decode_image(answer["ok"])
    assert (len(image.content), image.media_type) == (MAX_IMAGE, "image/png")


async def test_an_answer_too_large_for_nats_is_a_clear_error() -> None:
    answer = await run(FakeService(files=30_000), "files")
    error = decode_error(answer["error"])
    assert isinstance(error, ActionRejected)
    assert error_status(error) == (409, "too_large_for_front")
    assert "the command 'files' ran on the printer's worker" in error.message


async def test_an_image_too_large_is_refused_by_name() -> None:
    answer = await run(FakeService(image=MAX_IMAGE + 1), "thumbnail", path=".thumbs/big.png")
    error = decode_error(answer["error"])
    assert error.code == "too_large_for_front"
    assert error.message.startswith("p1: the thumbnail '.thumbs/big.png' is 701 kB")


async def test_an_unknown_op_says_the_worker_is_older() -> None:
    error = decode_error((await run(FakeService(), "fly"))["error"])
    assert type(error) is KyberCoreError
    assert "older than its front" in error.message


async def test_the_queues_ops_start_cancel_and_find_history_jobs() -> None:
    service = FakeService()
    assert await run(service, "print_start", name="kybercore/j1-a.gcode") == {"ok": None}
    assert await run(service, "print_cancel") == {"ok": None}
    assert service.moonraker.calls == [("print_start", "kybercore/j1-a.gcode"), ("print_cancel",)]
    by_id = await run(service, "history_job", upload_name="a.gcode", job_id="000002")
    assert by_id["ok"]["filename"] == "b.gcode"  # the id decides when it is bound
    by_name = await run(service, "history_job", upload_name="a.gcode", job_id="000009")
    assert by_name["ok"]["job_id"] == "000001"  # an unknown id: looked up by name
    assert (await run(service, "history_job", upload_name="z.gcode", job_id=None)) == {"ok": None}
