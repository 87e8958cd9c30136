"""The virtual MCU as a process: link handling, and a real Klippy driving it end to end.

Klippy is reached on its API unix socket (JSON objects terminated by 0x03), without Moonraker.
Measured figures are printed with a ``MEASURED`` prefix (``pytest -s`` shows them).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from kybercore.sim.mcu_protocol import encode_block
from kybercore.sim.printer_cfg import PrinterSpec, render_printer_cfg
from tests.helpers import wait_until

KLIPPY_PYTHON = Path(
    os.environ.get(
        "KYBERCORE_KLIPPY_PYTHON", "/root/.local/share/kybercore/venvs/klippy/bin/python"
    )
)
SRC = Path(__file__).resolve().parents[2] / "src"
# Fast enough that heating takes seconds, slow enough that bang-bang overshoot stays far
# below max_temp.
HEAT_FACTOR = 8


def _unique_link() -> Path:
    return Path(f"/tmp/klipper_host_test_{os.getpid()}_{uuid.uuid4().hex[:8]}")


def _start_mcu(link: Path, log: Path, *extra: str) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    with log.open("ab") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "kybercore.sim.mcu", "--link", str(link), *extra],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
        )


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


# ----- the MCU process on its own -------------------------------------------------------------


@pytest.mark.timeout(30)
def test_mcu_links_a_raw_pty_and_removes_the_link_on_sigterm(tmp_path: Path) -> None:
    link = _unique_link()
    os.symlink("/nonexistent/pts", link)  # stale: must be replaced
    proc = _start_mcu(link, tmp_path / "mcu.log")
    try:
        wait_until(lambda: os.path.realpath(link).startswith("/dev/pts/"), 10, "the pty link")
        # The link is usable: an identify request gets an answer.
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, encode_block(1, bytes([1, 0, 40])))  # identify offset=0 count=40
            reply = os.read(fd, 64)
        finally:
            os.close(fd)
        assert reply[2] == 0  # identify_response
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        assert not os.path.lexists(link)
    finally:
        _stop(proc)
        if os.path.islink(link):
            link.unlink()


@pytest.mark.timeout(30)
def test_mcu_refuses_a_link_path_that_is_not_a_symlink(tmp_path: Path) -> None:
    path = _unique_link()
    path.write_text("not a pty")
    try:
        proc = _start_mcu(path, tmp_path / "mcu.log")
        assert proc.wait(timeout=10) == 2
        assert "not a symlink" in (tmp_path / "mcu.log").read_text()
        assert path.read_text() == "not a pty"
    finally:
        path.unlink()


# ----- a real Klippy on the virtual MCU -------------------------------------------------------


class KlippyError(Exception):
    """Klippy answered a request with an error."""


class KlippyApi:
    """A client of Klippy's API socket: requests and subscription updates."""

    def __init__(self, path: Path) -> None:
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._sock.settimeout(60)
        self._sock.connect(str(path))
        self._buf = b""
        self._next_id = 0
        self.updates: list[dict[str, Any]] = []

    def close(self) -> None:
        self._sock.close()

    def _receive(self) -> dict[str, Any]:
        while b"\x03" not in self._buf:
            data = self._sock.recv(65536)
            if not data:
                raise ConnectionError("Klippy closed the API socket")
            self._buf += data
        raw, _, self._buf = self._buf.partition(b"\x03")
        message: dict[str, Any] = json.loads(raw)
        return message

    def call(self, method: str, **params: Any) -> Any:
        """Send one request and return its result (KlippyError on an error reply)."""
        self._next_id += 1
        request = {"id": self._next_id, "method": method, "params": params}
        self._sock.sendall(json.dumps(request).encode() + b"\x03")
        while True:
            message = self._receive()
            if message.get("id") == self._next_id:
                if "error" in message:
                    raise KlippyError(message["error"])
                return message["result"]
            if "params" in message:
                self.updates.append(message["params"])

    def gcode(self, script: str) -> float:
        """Run G-code and return how long Klippy took."""
        start = time.monotonic()
        self.call("gcode/script", script=script)
        return time.monotonic() - start

    def status(self, **objects: list[str] | None) -> dict[str, Any]:
        result: dict[str, Any] = self.call("objects/query", objects=objects)["status"]
        return result

    def state(self) -> str:
        state: str = self.call("info")["state"]
        return state


@dataclass
class Printer:
    """One virtual MCU and one Klippy on it."""

    dir: Path
    api_path: Path
    mcu: subprocess.Popen[bytes]
    klippy: subprocess.Popen[bytes]
    ready_seconds: float
    api: KlippyApi

    @property
    def gcodes(self) -> Path:
        return self.dir / "gcodes"

    def reconnect(self, timeout: float = 30) -> float:
        """Wait until Klippy is ready again on a new API connection; returns the seconds."""
        self.api.close()

        def ready() -> bool:
            try:
                self.api = KlippyApi(self.api_path)
                if self.api.state() == "ready":
                    return True
                self.api.close()
            except (OSError, ConnectionError):
                pass
            return False

        return wait_until(ready, timeout, "Klippy ready")

    def log(self) -> str:
        return (self.dir / "klippy.log").read_text(errors="replace")


@pytest.fixture(scope="module")
def printer(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Printer]:
    if not KLIPPY_PYTHON.exists():
        pytest.skip(f"no Klippy interpreter at {KLIPPY_PYTHON} (set KYBERCORE_KLIPPY_PYTHON)")
    base = tmp_path_factory.mktemp("vprinter")
    (base / "gcodes").mkdir()
    link = _unique_link()
    cfg = base / "printer.cfg"
    cfg.write_text(
        render_printer_cfg(PrinterSpec(mcu_serial=str(link), gcodes_dir=str(base / "gcodes")))
    )
    # Unix socket paths hold 108 bytes: keep the socket out of a possibly long TMPDIR.
    short = Path(tempfile.mkdtemp(prefix="kc-", dir="/tmp"))
    api_path = short / "klippy.sock"
    mcu = _start_mcu(link, base / "mcu.log", "--heat-rate", str(HEAT_FACTOR))
    klippy: subprocess.Popen[bytes] | None = None
    try:
        wait_until(link.exists, 10, "the MCU's pty link")
        start = time.monotonic()
        with (base / "klippy.out").open("ab") as out:
            klippy = subprocess.Popen(
                [
                    str(KLIPPY_PYTHON),
                    "-m",
                    "klippy.klippy",
                    str(cfg),
                    "-a",
                    str(api_path),
                    "-I",
                    str(short / "printer"),
                    "-l",
                    str(base / "klippy.log"),
                ],
                stdout=out,
                stderr=subprocess.STDOUT,
            )
        wait_until(api_path.exists, 60, "Klippy's API socket")
        vprinter = Printer(base, api_path, mcu, klippy, 0.0, KlippyApi(api_path))
        vprinter.reconnect(timeout=60)
        vprinter.ready_seconds = time.monotonic() - start
        print(f"\nMEASURED Klippy start to ready: {vprinter.ready_seconds:.2f} s")
        yield vprinter
        vprinter.api.close()
    finally:
        if klippy is not None:
            _stop(klippy)
        shutil.rmtree(short, ignore_errors=True)
        _stop(mcu)
        if os.path.islink(link):
            link.unlink()


@pytest.mark.integration
@pytest.mark.timeout(120)
def test_klippy_reaches_ready(printer: Printer) -> None:
    # How fast is printed (MEASURED), not asserted: the fixture gives it 60 s to be ready.
    assert printer.api.state() == "ready"
    mcu = printer.api.status(mcu=None)["mcu"]
    assert mcu["mcu_version"] == "kybercore-virtual-mcu"


@pytest.mark.integration
@pytest.mark.timeout(120)
def test_g28_homes_exactly_to_zero(printer: Printer) -> None:
    seconds = printer.api.gcode("G28")
    print(f"\nMEASURED G28: {seconds:.2f} s")
    toolhead = printer.api.status(toolhead=["position", "homed_axes"])["toolhead"]
    assert toolhead["homed_axes"] == "xyz"
    assert toolhead["position"][:3] == [0.0, 0.0, 0.0]
    printer.api.gcode("G1 X100 Y50 Z10 F6000\nM400")
    assert printer.api.status(toolhead=["position"])["toolhead"]["position"][:3] == [
        100.0,
        50.0,
        10.0,
    ]


@pytest.mark.integration
@pytest.mark.timeout(120)
def test_heaters_rise_toward_their_targets(printer: Printer) -> None:
    def temps() -> tuple[float, float]:
        status = printer.api.status(extruder=["temperature"], heater_bed=["temperature"])
        return status["extruder"]["temperature"], status["heater_bed"]["temperature"]

    start_hotend, start_bed = temps()
    assert start_hotend < 100
    started = time.monotonic()
    printer.api.gcode("M104 S200\nM140 S60")

    def rising() -> bool:
        hotend, bed = temps()
        return hotend > start_hotend + 5 and bed > start_bed + 1

    wait_until(rising, 30, "both heaters to rise toward their targets")
    printer.api.gcode("M190 S60\nM109 S200")
    print(
        f"\nMEASURED heat to bed 60 C + hotend 200 C at --heat-rate {HEAT_FACTOR}: "
        f"{time.monotonic() - started:.1f} s"
    )
    hotend, bed = temps()
    assert 195 <= hotend <= 240
    assert 55 <= bed <= 70
    printer.api.gcode("M104 S0\nM140 S0")


def _write_job(path: Path, moves: int) -> None:
    lines = [
        "; sliced-style test job",
        "M140 S60",
        "M104 S200",
        "G28",
        "M190 S60",
        "M109 S200",
        "G90",
        "M83",
        "G1 Z0.3 F600",
        "G1 E3 F1800",
    ]
    for i in range(moves):
        lines.append(f"G1 X{40 + 10 * (i % 2)} Y{40 + i * 0.2:.1f} E0.3 F3000")
    lines += ["M104 S0", "M140 S0", "M84"]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.integration
@pytest.mark.timeout(120)
def test_print_pause_resume_cancel(printer: Printer) -> None:
    _write_job(printer.gcodes / "job.gcode", moves=400)
    api = printer.api
    api.call(
        "objects/subscribe",
        objects={"print_stats": ["state"], "virtual_sdcard": ["progress"]},
        response_template={},
    )
    api.gcode("SDCARD_PRINT_FILE FILENAME=job.gcode")

    def progress() -> float:
        value: float = api.status(virtual_sdcard=["progress"])["virtual_sdcard"]["progress"]
        return value

    # Progress moves once homing and heating inside the job are done and moves stream.
    wait_until(lambda: progress() > 0.05, 60, "print progress")
    assert api.status(print_stats=["state"])["print_stats"]["state"] == "printing"
    first = progress()
    wait_until(lambda: progress() > first, 10, "progress to increase")

    seconds = api.gcode("PAUSE")
    assert api.status(print_stats=["state"])["print_stats"]["state"] == "paused"
    paused_at = progress()
    # Nothing moves while paused, for a full second of Klippy's own clock: print_stats'
    # total_duration keeps counting through a pause, print_duration does not.
    paused = api.status(print_stats=["total_duration", "print_duration"])["print_stats"]

    def a_paused_second() -> bool:
        now = api.status(print_stats=["total_duration", "print_duration"])["print_stats"]
        assert progress() == paused_at
        assert now["print_duration"] == paused["print_duration"]
        return bool(now["total_duration"] >= paused["total_duration"] + 1.0)

    wait_until(a_paused_second, 30, "a second of Klippy's clock while paused")
    print(f"\nMEASURED PAUSE: {seconds:.2f} s")

    api.gcode("RESUME")
    assert api.status(print_stats=["state"])["print_stats"]["state"] == "printing"
    wait_until(lambda: progress() > paused_at, 10, "progress after resume")

    seconds = api.gcode("CANCEL_PRINT")
    print(f"\nMEASURED CANCEL_PRINT: {seconds:.2f} s")
    status = api.status(print_stats=["state"], extruder=["target"], heater_bed=["target"])
    assert status["print_stats"]["state"] == "cancelled"
    assert status["extruder"]["target"] == 0
    assert status["heater_bed"]["target"] == 0
    # The subscription saw the state changes as they happened.
    api.state()  # collects any updates queued so far
    seen = [
        u["status"]["print_stats"]["state"]
        for u in api.updates
        if "print_stats" in u.get("status", {})
    ]
    assert seen[:1] == ["printing"]
    assert "paused" in seen


@pytest.mark.integration
@pytest.mark.timeout(120)
def test_emergency_stop_then_firmware_restart(printer: Printer) -> None:
    start = time.monotonic()
    printer.api.call("emergency_stop")
    wait_until(lambda: printer.api.state() == "shutdown", 10, "shutdown")
    print(f"\nMEASURED emergency_stop to shutdown: {time.monotonic() - start:.2f} s")
    # The MCU itself answered the emergency_stop command with its shutdown message.
    wait_until(
        lambda: "MCU 'mcu' shutdown: Command request" in printer.log(),
        10,
        "the MCU's shutdown report",
    )
    with pytest.raises(KlippyError, match="shutdown"):
        printer.api.gcode("G28")

    # Klippy may drop the API connection while it restarts.
    with contextlib.suppress(ConnectionError, OSError):
        printer.api.gcode("FIRMWARE_RESTART")
    seconds = printer.reconnect()
    print(f"\nMEASURED FIRMWARE_RESTART to ready: {seconds:.2f} s")
    assert "Attempting MCU 'mcu' reset command" in printer.log()
    assert printer.log().count("Sending MCU 'mcu' printer configuration") == 2
    # The rebooted MCU runs motion again.
    printer.api.gcode("G28 X")
    toolhead = printer.api.status(toolhead=["position", "homed_axes"])["toolhead"]
    assert toolhead["homed_axes"] == "x"
    assert toolhead["position"][0] == 0.0
