"""The reads a front makes through the printers' workers, against real processes (a
nats-server, 2 ingest workers, a front, real virtual printers): the macros, the print's
objects, the temperature graph, a thumbnail, the webcam list, a snapshot and the live
stream answer as ``kybercore serve`` answers them, from what the printer's Moonraker and
its camera really have."""

from __future__ import annotations

import io
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import PIL.Image
import pytest

from kybercore.core.macros import macros_of
from kybercore.scale.wire import MAX_IMAGE
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_until
from tests.scale.cluster import Cluster

pytestmark = pytest.mark.integration

SAMPLES = Path(__file__).resolve().parents[2] / "src/kybercore/sim/samples"
JPEG = b"\xff\xd8\xff"
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def front(cluster: Cluster) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=f"{cluster.front.url}/api/printers", timeout=30) as client:
        yield client


def stack(stacks: list[PrinterStack], name: str) -> PrinterStack:
    return next(s for s in stacks if s.options.name == name)


def moonraker(printer: PrinterStack, path: str, **params: Any) -> Any:
    """What the printer's own Moonraker answers (``result``)."""
    answer = httpx.get(f"{printer.url}{path}", params=params, timeout=30)
    answer.raise_for_status()
    return answer.json()["result"]


def test_the_macros_are_those_of_klippers_configuration(
    front: httpx.Client, fleet_stacks: list[PrinterStack]
) -> None:
    answer = front.get("/fleet-a/macros")
    assert answer.status_code == 200, answer.text
    printer = stack(fleet_stacks, "fleet-a")
    status = moonraker(printer, "/printer/objects/query", configfile="config")["status"]
    expected = macros_of(status["configfile"]["config"])
    assert expected, "the virtual printer has macros"
    assert answer.json() == [{"name": m.name, "description": m.description} for m in expected]
    by_name = {m["name"]: m["description"] for m in answer.json()}
    assert by_name["PARK"] == "Move the toolhead to the back corner, clear of the part"
    missing = front.get("/nope/macros")
    assert (missing.status_code, missing.json()["error"]["code"]) == (404, "unknown_printer")


def test_the_prints_objects_are_read_from_klipper_by_the_owner(front: httpx.Client) -> None:
    # Idle: Klipper has [exclude_object] and no objects (a print defines them).
    answer = front.get("/fleet-a/objects")
    assert answer.status_code == 200, answer.text
    assert answer.json() == {"available": True, "objects": [], "excluded": [], "current": None}


def test_the_temperature_graph_follows_a_target_set_through_the_front(
    front: httpx.Client,
) -> None:
    def extruder() -> dict[str, list[Any]]:
        answer = front.get("/fleet-b/temperatures", params={"minutes": 5})
        assert answer.status_code == 200, answer.text
        body = answer.json()
        assert body["printer"] == "fleet-b"
        assert "heater_bed" in body["series"]
        series: dict[str, list[Any]] = body["series"]["extruder"]
        return series

    target = 37.0  # reached at once by no printer here: only this test sets it
    answer = front.post("/fleet-b/actions/set_temperature", json={"extruder": target})
    assert answer.status_code == 200, answer.text
    try:
        wait_until(lambda: target in extruder()["target"], 30, "the graph shows the new target")
    finally:
        front.post("/fleet-b/actions/set_temperature", json={"extruder": 0})
    series = extruder()
    assert len(series["t"]) == len(series["temperature"]) == len(series["target"])
    assert series["t"] == sorted(series["t"])
    missing = front.get("/nope/temperatures")
    assert (missing.status_code, missing.json()["error"]["code"]) == (404, "unknown_printer")
    assert front.get("/fleet-b/temperatures", params={"minutes": 31}).status_code == 422


def test_a_thumbnail_is_the_image_moonraker_serves(
    front: httpx.Client, fleet_stacks: list[PrinterStack]
) -> None:
    printer = stack(fleet_stacks, "fleet-c")
    name = "front-reads-thumbnail.gcode"
    sample = (SAMPLES / "calibration_cube_10mm_petg.gcode").read_bytes()
    upload = httpx.post(
        f"{printer.url}/server/files/upload", files={"file": (name, sample)}, timeout=30
    )
    upload.raise_for_status()
    try:

        def thumbnails() -> list[dict[str, Any]]:
            meta = front.get("/fleet-c/files/metadata", params={"filename": name})
            found: list[dict[str, Any]] = meta.json().get("thumbnails", [])
            return found if meta.status_code == 200 else []

        wait_until(lambda: bool(thumbnails()), 30, "Moonraker's metadata of the file")
        path = thumbnails()[0]["relative_path"]
        answer = front.get("/fleet-c/files/thumbnail", params={"path": path})
        assert answer.status_code == 200, answer.text
        direct = httpx.get(f"{printer.url}/server/files/gcodes/{path}", timeout=30)
        direct.raise_for_status()
        assert answer.content == direct.content
        assert answer.content.startswith(PNG)
        assert answer.headers["content-type"] == "image/png"
        assert answer.headers["cache-control"] == "private, max-age=300"
    finally:
        httpx.delete(f"{printer.url}/server/files/gcodes/{name}", timeout=30)
    gone = front.get("/fleet-c/files/thumbnail", params={"path": ".thumbs/nope.png"})
    assert gone.status_code == 404, gone.text


def test_an_image_too_large_for_nats_is_refused_by_name(
    front: httpx.Client, fleet_stacks: list[PrinterStack]
) -> None:
    printer = stack(fleet_stacks, "fleet-c")
    huge = printer.gcodes_dir / ".thumbs" / "front-reads-huge.png"
    huge.parent.mkdir(exist_ok=True)
    huge.write_bytes(PNG + os.urandom(MAX_IMAGE))
    try:
        path = ".thumbs/front-reads-huge.png"
        # Moonraker serves it (serve would relay it); one NATS message cannot carry it.
        direct = httpx.get(f"{printer.url}/server/files/gcodes/{path}", timeout=30)
        assert direct.status_code == 200
        answer = front.get("/fleet-c/files/thumbnail", params={"path": path})
        assert answer.status_code == 409, answer.text
        error = answer.json()["error"]
        assert error["code"] == "too_large_for_front"
        assert error["message"].startswith(f"fleet-c: the thumbnail '{path}' is 701 kB")
    finally:
        huge.unlink()


def test_the_webcams_and_a_snapshot(front: httpx.Client, fleet_stacks: list[PrinterStack]) -> None:
    answer = front.get("/fleet-a/webcams")
    assert answer.status_code == 200, answer.text
    listed = moonraker(stack(fleet_stacks, "fleet-a"), "/server/webcams/list")["webcams"]
    enabled = [c["name"] for c in listed if c.get("enabled", True)]
    assert [c["name"] for c in answer.json()] == enabled
    [cam] = answer.json()
    assert cam["name"] == "kybercam"
    assert cam["snapshot_url"] == "/api/printers/fleet-a/webcams/kybercam/snapshot"
    assert cam["stream_url"] == "/api/printers/fleet-a/webcams/kybercam/stream"

    snapshot = front.get("/fleet-a/webcams/kybercam/snapshot")
    assert snapshot.status_code == 200, snapshot.text
    assert snapshot.headers["content-type"] == "image/jpeg"
    assert snapshot.headers["cache-control"] == "no-store"
    assert snapshot.content.startswith(JPEG)
    assert snapshot.content.endswith(b"\xff\xd9")  # a whole JPEG, not a cut one
    # A picture of that camera: as large as the one it serves directly (frames differ).
    camera = stack(fleet_stacks, "fleet-a").webcam_url
    direct = httpx.get(f"{camera}/snapshot", timeout=30)
    direct.raise_for_status()
    with PIL.Image.open(io.BytesIO(snapshot.content)) as relayed:
        relayed.load()  # decodes the whole picture: a cut JPEG raises
        with PIL.Image.open(io.BytesIO(direct.content)) as original:
            assert (relayed.format, relayed.size) == ("JPEG", original.size)

    unknown = front.get("/fleet-a/webcams/nope/snapshot")
    assert unknown.status_code == 404
    assert "/api/printers/fleet-a/webcams" in unknown.json()["error"]["message"]


def mjpeg(answer: httpx.Response, pictures: int) -> bytes:
    """The stream's bytes until ``pictures`` JPEGs have begun."""
    received = b""
    for chunk in answer.iter_raw():
        received += chunk
        if received.count(JPEG) >= pictures:
            break
    return received


def test_the_webcams_live_stream_is_relayed_by_the_printers_owner(front: httpx.Client) -> None:
    with front.stream("GET", "/fleet-a/webcams/kybercam/stream") as answer:
        assert answer.status_code == 200, answer.read()
        assert answer.headers["content-type"].startswith("multipart/x-mixed-replace")
        assert answer.headers["cache-control"] == "no-store"
        received = mjpeg(answer, 3)
    # Whole pictures, one after another: the first part's JPEG ends before the second.
    boundary = answer.headers["content-type"].split("boundary=")[1].encode()
    first = received.split(b"--" + boundary)[1]
    picture = first[first.index(JPEG) :].rstrip(b"\r\n")
    with PIL.Image.open(io.BytesIO(picture)) as image:
        image.load()  # a cut JPEG raises
        assert image.format == "JPEG"
    unknown = front.get("/fleet-a/webcams/nope/stream")
    assert unknown.status_code == 404, unknown.text


def test_a_printers_streams_are_limited_and_one_browser_leaving_frees_one(
    front: httpx.Client,
) -> None:
    """As in one process: four streams of a printer at once, the fifth refused; a browser
    that leaves frees its stream on the owner, which also closes the camera's."""
    url = "/fleet-b/webcams/kybercam/stream"
    opened = [front.send(front.build_request("GET", url), stream=True) for _ in range(4)]
    try:
        for answer in opened:
            assert answer.status_code == 200, answer.read()
            mjpeg(answer, 1)
        fifth = front.get(url)
        assert fifth.status_code == 409, fifth.text
        assert fifth.json()["error"]["code"] == "too_many_streams"
        opened.pop().close()

        def another_opens() -> bool:
            with front.stream("GET", url) as answer:
                return answer.status_code == 200 and JPEG in mjpeg(answer, 1)

        wait_until(another_opens, 30, "a stream freed by a browser that left")
    finally:
        for answer in opened:
            answer.close()
