"""Start and stop virtual printers: virtual MCU + real Klippy + real Moonraker + a webcam,
per printer.

Every process is started here and stopped here, by PID. Nothing is left behind when a
start fails half-way: what was started is stopped before the error is raised.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Final

import httpx

from kybercore.errors import LaunchError
from kybercore.sim.printer_cfg import PrinterSpec, render_printer_cfg
from kybercore.sim.runtime import KLIPPY, MOONRAKER, mcu_command

log = logging.getLogger(__name__)

READY_TIMEOUT: Final = 60.0
_EXCEPTION_LINE: Final = re.compile(r"[A-Za-z_][\w.]*(: .*)?$")
_STOP_GRACE: Final = 5.0
# The logs whose last lines explain a failed start.
_LOG_FILES: Final = (
    "klippy.log", "moonraker.log", "klippy.out", "moonraker.out", "mcu.out", "webcam.out"
)  # fmt: skip


@dataclass(frozen=True)
class StackOptions:
    """What makes one virtual printer different from another."""

    name: str
    port: int = 0
    """Moonraker's port on 127.0.0.1; 0 picks a free one."""
    size: tuple[float, float, float] = (220.0, 220.0, 250.0)
    nozzle_diameter: float = 0.4
    extruder_max_temp: float = 280.0
    bed_max_temp: float = 110.0
    heat_rate: float | None = None
    """Heater speed for the thermal model; None keeps the realistic default."""
    trusted_clients: tuple[str, ...] = ("127.0.0.1/32",)
    with_klippy: bool = True
    """False starts Moonraker alone, as on a host whose Klippy never came up."""
    mdns_hostname: str | None = None
    """Enables Moonraker's ``[zeroconf]`` under this host name. Moonraker then announces on
    every interface of the machine, not only its own address: start such a stack inside a
    loopback-only network namespace, or it multicasts on the LAN."""


@dataclass
class PrinterStack:
    """One running virtual printer and the four processes behind it."""

    options: StackOptions
    data_dir: Path
    port: int = 0
    webcam_port: int = 0
    _procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    _logs: list[IO[bytes]] = field(default_factory=list)

    @property
    def url(self) -> str:
        """Moonraker's base URL."""
        return f"http://127.0.0.1:{self.port}"

    @property
    def webcam_url(self) -> str:
        """The webcam's base URL (``/snapshot``, ``/stream``)."""
        return f"http://127.0.0.1:{self.webcam_port}"

    @property
    def gcodes_dir(self) -> Path:
        """Where Moonraker and Klippy's virtual SD card keep G-code files."""
        return self.data_dir / "gcodes"

    @property
    def mcu_link(self) -> Path:
        """The serial path Klippy opens; a symlink to the MCU's pty."""
        # Klippy treats serial paths with this exact prefix as a pipe (no baud rate).
        return Path(f"/tmp/klipper_host_kc_{self.options.name}_{self._tag}")  # noqa: S108

    @property
    def comms_dir(self) -> Path:
        """Where the sockets and Klippy's input pty live: a short folder of this stack's own.

        A Unix socket path holds at most 108 bytes, and the data folder can be anywhere (a
        long home, a CI workspace, a long ``TMPDIR``), so the sockets never live under it:
        ``data_dir/comms`` is a link to this folder, which Moonraker follows.
        """
        return Path(f"/tmp/kc-{self._tag}")  # noqa: S108

    @property
    def pids(self) -> dict[str, int]:
        """PIDs of the processes this stack started and that are still running."""
        return {name: p.pid for name, p in self._procs.items() if p.poll() is None}

    def __post_init__(self) -> None:
        self._tag = uuid.uuid4().hex[:8]

    # -- start / stop ------------------------------------------------------------------

    def start(self) -> None:
        """Write configuration and start MCU, Klippy, Moonraker and the webcam (does not wait
        for ready)."""
        try:
            self.port = self.options.port or free_port()
            if self.options.port:
                ensure_port_free(self.port)
            self.webcam_port = free_port()
            self._write_config()
            if self.options.with_klippy:
                self.start_mcu()
                self.start_klippy()
            self.start_moonraker()
            self.start_webcam()
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        """Stop every process this stack started: webcam, Moonraker, Klippy, then the MCU."""
        for name in ("webcam", "moonraker", "klippy", "mcu"):
            self._stop(name)
        for handle in self._logs:
            handle.close()
        self._logs.clear()
        shutil.rmtree(self.comms_dir, ignore_errors=True)

    def start_mcu(self) -> None:
        """Start the virtual MCU and wait for its pty link to appear."""
        self._spawn("mcu", mcu_command(self.mcu_link, self.options.heat_rate))
        deadline = time.monotonic() + 10
        while not self.mcu_link.exists():
            self._check_alive("mcu")
            if time.monotonic() > deadline:
                raise LaunchError(f"{self.options.name}: the virtual MCU did not create its pty")
            time.sleep(0.02)

    def start_klippy(self) -> None:
        """Start Klippy on printer.cfg with its API socket where Moonraker expects it."""
        self._spawn(
            "klippy",
            [
                str(KLIPPY.python),
                "-m",
                "klippy.klippy",
                str(self.data_dir / "config" / "printer.cfg"),
                "-a",
                str(self._klippy_socket),
                # Its own input pty: printers started together never race for /tmp/printer.
                "-I",
                str(self.comms_dir / "printer"),
                "-l",
                str(self.data_dir / "logs" / "klippy.log"),
            ],
        )

    def start_moonraker(self) -> None:
        """Start Moonraker on this stack's port."""
        self._spawn(
            "moonraker",
            [
                str(MOONRAKER.python),
                "-m",
                "moonraker",
                "-d",
                str(self.data_dir),
                "-c",
                str(self.data_dir / "config" / "moonraker.conf"),
                "-l",
                str(self.data_dir / "logs" / "moonraker.log"),
            ],
        )

    def start_webcam(self) -> None:
        """Start the webcam, which draws this printer's bed from its Moonraker's status.

        A process of its own, like the MCU: drawing and JPEG encoding in the MCU process
        would hold its GIL and jitter the clock Klippy synchronises to, and neither Klippy
        nor Moonraker is ours to extend. Idle it costs memory only: no polling, no drawing.
        """
        self._spawn(
            "webcam",
            [
                sys.executable,
                "-m",
                "kybercore.sim.webcam",
                "--name",
                self.options.name,
                "--port",
                str(self.webcam_port),
                "--moonraker",
                self.url,
            ],
        )

    def stop_webcam(self) -> None:
        """Stop the webcam only (tests use this for a camera that died)."""
        self._stop("webcam")

    def stop_moonraker(self) -> None:
        """Stop Moonraker only (tests use this to take a printer off the network)."""
        self._stop("moonraker")

    def kill_klippy(self) -> None:
        """SIGKILL Klippy, as a crash would."""
        proc = self._procs.pop("klippy", None)
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()

    def wait_ready(self, timeout: float = READY_TIMEOUT) -> None:
        """Block until Moonraker reports Klippy ``ready`` and the webcam listens; explain with
        log tails if not."""
        deadline = time.monotonic() + timeout
        state = "not answering"
        with httpx.Client(timeout=2.0, trust_env=False) as http:
            while time.monotonic() < deadline:
                for name in ("mcu", "klippy", "moonraker", "webcam"):
                    self._check_alive(name)
                self._check_klippy_started()
                with contextlib.suppress(httpx.HTTPError, ValueError):
                    info = http.get(f"{self.url}/server/info").json()["result"]
                    state = info["klippy_state"]
                    if state == "ready" and _listening(self.webcam_port):
                        return
                    if state == "error":
                        # A config error is final: Klippy waits for a RESTART that won't come.
                        info = http.get(f"{self.url}/printer/info").json()["result"]
                        state = f"error: {info.get('state_message', '').strip()}"
                        break
                time.sleep(0.1)
            else:
                state = f"{state} after {timeout:g} s"
        raise LaunchError(
            f"{self.options.name}: Klippy did not become ready (state: {state}).\n{self._tails()}"
        )

    # -- internals ---------------------------------------------------------------------

    @property
    def _klippy_socket(self) -> Path:
        return self.comms_dir / "klippy.sock"

    def _write_config(self) -> None:
        for sub in ("config", "logs", "gcodes", "database", "misc"):
            (self.data_dir / sub).mkdir(parents=True, exist_ok=True)
        self.comms_dir.mkdir(mode=0o700, exist_ok=True)
        link = self.data_dir / "comms"
        if link.is_dir() and not link.is_symlink():
            shutil.rmtree(link)  # a folder of stale sockets from an older layout
        link.unlink(missing_ok=True)
        link.symlink_to(self.comms_dir)
        # Moonraker downloads usb.ids at start unless the file exists: we have no internet.
        (self.data_dir / "misc" / "usb.ids").touch()
        opts = self.options
        spec = PrinterSpec(
            mcu_serial=str(self.mcu_link),
            gcodes_dir=str(self.gcodes_dir),
            size_x=opts.size[0],
            size_y=opts.size[1],
            size_z=opts.size[2],
            nozzle_diameter=opts.nozzle_diameter,
            extruder_max_temp=opts.extruder_max_temp,
            bed_max_temp=opts.bed_max_temp,
        )
        (self.data_dir / "config" / "printer.cfg").write_text(render_printer_cfg(spec))
        conf = render_moonraker_conf(
            self.port, self._klippy_socket, opts.trusted_clients, self.webcam_url,
            mdns_hostname=opts.mdns_hostname,
        )  # fmt: skip
        (self.data_dir / "config" / "moonraker.conf").write_text(conf)

    def _spawn(self, name: str, command: list[str]) -> None:
        self._check_not_running(name)
        logfile = open(self.data_dir / "logs" / f"{name}.out", "ab")  # noqa: SIM115
        self._logs.append(logfile)
        # Moonraker names upload temp files after the clock: printers sharing /tmp collide.
        tmp = self.data_dir / "tmp"
        tmp.mkdir(exist_ok=True)
        self._procs[name] = subprocess.Popen(
            command,
            env={**os.environ, "TMPDIR": str(tmp)},
            stdout=logfile,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            # Ctrl-C in a terminal must reach KyberCore only; it stops these in order.
            start_new_session=True,
        )

    def _check_not_running(self, name: str) -> None:
        proc = self._procs.get(name)
        if proc is not None and proc.poll() is None:
            raise LaunchError(f"{self.options.name}: {name} is already running (pid {proc.pid})")

    def _check_klippy_started(self) -> None:
        """Fail at once when Klippy died at start: its process can outlive its main thread."""
        out = self.data_dir / "logs" / "klippy.out"
        try:
            text = out.read_text(errors="replace")
        except OSError:
            return
        if "Traceback" not in text:
            return
        # The traceback is written in pieces: it is whole once its last line, the exception
        # itself ("OSError: AF_UNIX path too long"), is written and newline-terminated.
        last = text.rstrip("\n").splitlines()[-1]
        if text.endswith("\n") and _EXCEPTION_LINE.match(last):
            cause = last
            raise LaunchError(
                f"{self.options.name}: Klippy failed at start ({cause}).\n{self._tails()}"
            )

    def _check_alive(self, name: str) -> None:
        proc = self._procs.get(name)
        if proc is not None and proc.poll() is not None:
            raise LaunchError(
                f"{self.options.name}: {name} exited with code {proc.returncode}.\n{self._tails()}"
            )

    def _stop(self, name: str) -> None:
        proc = self._procs.pop(name, None)
        if proc is None or proc.poll() is not None:
            return
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(_STOP_GRACE)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()

    def _tails(self) -> str:
        parts = []
        for name in _LOG_FILES:
            path = self.data_dir / "logs" / name
            if path.exists():
                lines = path.read_text(errors="replace").splitlines()[-12:]
                parts.append(f"--- last lines of {path} ---\n" + "\n".join(lines))
        return "\n".join(parts)


def render_moonraker_conf(
    port: int, klippy_socket: Path, trusted: tuple[str, ...], webcam_url: str, *,
    mdns_hostname: str | None = None,
) -> str:  # fmt: skip
    """A moonraker.conf for a local printer that never reaches out to the internet, with its
    webcam registered as a real one is, so clients find it in ``/server/webcams/list``."""
    trusted_lines = "".join(f"\n    {net}" for net in trusted)
    # SSDP stays off: only the mDNS announcement is KyberCore's to find.
    zeroconf = f"\n[zeroconf]\nmdns_hostname: {mdns_hostname}\nenable_ssdp: False\n"
    return f"""\
[server]
host: 127.0.0.1
port: {port}
klippy_uds_address: {klippy_socket}

[authorization]
trusted_clients:{trusted_lines}
cors_domains:
    *

[machine]
provider: none

[announcements]
enable_moonlight: False

[history]

[file_manager]
enable_object_processing: False

[webcam kybercam]
location: printer
# Snapshots polled at target_fps: what Mainsail and Fluidd suggest for many cameras.
service: mjpegstreamer-adaptive
target_fps: 2
target_fps_idle: 1
stream_url: {webcam_url}/stream
snapshot_url: {webcam_url}/snapshot
aspect_ratio: 4:3
{zeroconf if mdns_hostname else ""}"""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _listening(port: int) -> bool:
    """True when something accepts connections on ``127.0.0.1:port``."""
    with socket.socket() as sock:
        return sock.connect_ex(("127.0.0.1", port)) == 0


def ensure_port_free(port: int, host: str = "127.0.0.1") -> None:
    """Raise a clear error when something already listens on ``host:port``."""
    with socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError as exc:
            raise LaunchError(
                f"Cannot listen on {host}:{port} ({exc.strerror}). Stop what uses that port "
                "or choose another with --port."
            ) from None


@contextlib.contextmanager
def running_stacks(
    base_dir: Path, options: list[StackOptions], timeout: float = READY_TIMEOUT
) -> Iterator[list[PrinterStack]]:
    """Start several printers at once, wait until all are ready, stop them all on exit."""
    stacks = [PrinterStack(opts, base_dir / opts.name) for opts in options]
    try:
        for stack in stacks:
            stack.start()
        for stack in stacks:
            stack.wait_ready(timeout)
        yield stacks
    finally:
        for stack in stacks:
            stack.stop()
