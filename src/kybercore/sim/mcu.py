"""A virtual Klipper MCU on a pseudo-terminal, for a real, unmodified Klippy to drive.

Run ``python -m kybercore.sim.mcu --link /tmp/klipper_host_<name>`` and point printer.cfg's
``[mcu] serial`` at the link (see `kybercore.sim.printer_cfg`). Standard library only, one
process per printer; SIGTERM or SIGINT stops it and removes the link.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import select
import signal
import stat
import sys
import termios
import time
import tty
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Final

from kybercore.sim.firmware import ThermalSettings, VirtualFirmware
from kybercore.sim.mcu_protocol import CLOCK_FREQ

log = logging.getLogger("kybercore.sim.mcu")

# Output the host does not read (Klippy stopped or restarting) is dropped past this size.
_MAX_PENDING_OUTPUT: Final = 64 * 1024
# Linux Unix98 pty slaves (/dev/pts/N) use device majors 136-143.
_PTY_SLAVE_MAJORS: Final = range(136, 144)


class LinkError(Exception):
    """The --link path cannot be taken over."""


def _is_live_pty(path: str) -> bool:
    try:
        st = os.stat(path)
    except OSError:
        return False
    return stat.S_ISCHR(st.st_mode) and os.major(st.st_rdev) in _PTY_SLAVE_MAJORS


class PtyLink:
    """A raw pty whose slave side is symlinked at `link`. The slave fd stays open here so the
    master never reads EIO while Klippy is disconnected or restarting."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.fd, self._slave = os.openpty()
        try:
            tty.setraw(self._slave)
            os.set_blocking(self.fd, False)
            self.slave_name = os.ttyname(self._slave)
            self._claim()
        except BaseException:
            os.close(self.fd)
            os.close(self._slave)
            raise
        self._out = bytearray()

    def _claim(self) -> None:
        link = self.link
        if os.path.lexists(link):
            if not link.is_symlink():
                raise LinkError(f"{link} exists and is not a symlink; refusing to replace it")
            target = os.readlink(link)
            if target != self.slave_name and _is_live_pty(target):
                raise LinkError(
                    f"{link} points to {target}, a live pty: another virtual MCU "
                    "is probably serving it"
                )
            log.info("Replacing stale link %s -> %s", link, target)
        # Symlink then rename, so Klippy never sees the path missing or half made.
        tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
        tmp.unlink(missing_ok=True)
        os.symlink(self.slave_name, tmp)
        os.replace(tmp, link)

    @property
    def has_output(self) -> bool:
        """True while bytes wait for the host to make room."""
        return bool(self._out)

    def write(self, data: bytes) -> None:
        """Queue `data` for the host and send what the pty accepts now."""
        self._out += data
        if len(self._out) > _MAX_PENDING_OUTPUT:
            log.debug("Host is not reading; dropping %d bytes", len(self._out))
            self._out.clear()
        self.flush()

    def flush(self) -> None:
        """Send queued output as far as the pty buffer allows."""
        while self._out:
            try:
                sent = os.write(self.fd, self._out)
            except BlockingIOError:
                return
            del self._out[:sent]

    def read(self) -> bytes:
        """Whatever the host has sent (may be empty)."""
        try:
            return os.read(self.fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                return b""
            raise

    def discard_buffers(self) -> None:
        """Drop bytes in flight both ways, as a rebooting MCU loses them."""
        self._out.clear()
        termios.tcflush(self._slave, termios.TCIOFLUSH)

    def close(self) -> None:
        """Remove the link (if it is still ours) and close the pty."""
        try:
            if os.readlink(self.link) == self.slave_name:
                self.link.unlink()
        except OSError:
            pass
        os.close(self.fd)
        os.close(self._slave)


def monotonic_clock() -> Callable[[], int]:
    """An MCU clock: CLOCK_FREQ ticks per second of time.monotonic(), from zero at start."""
    origin = time.monotonic()
    return lambda: int((time.monotonic() - origin) * CLOCK_FREQ)


def serve(link: PtyLink, firmware: VirtualFirmware, clock: Callable[[], int], stop_fd: int) -> None:
    """Run the MCU until `stop_fd` becomes readable."""
    while True:
        timeout = max(0.0, (firmware.next_wake() - clock()) / CLOCK_FREQ)
        writers = [link.fd] if link.has_output else []
        readable, writable, _ = select.select([link.fd, stop_fd], writers, [], timeout)
        if stop_fd in readable:
            return
        if link.fd in readable:
            data = link.read()
            if data:
                firmware.receive(data)
            else:
                time.sleep(0.01)  # EIO or a spurious wake-up: do not spin
        if writable:
            link.flush()
        firmware.run_timers()


def _positive(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError("must be > 0")
    return value


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    parser = argparse.ArgumentParser(
        prog="python -m kybercore.sim.mcu",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--link",
        type=Path,
        required=True,
        help="symlink to create for the pty, e.g. /tmp/klipper_host_printer1",
    )
    parser.add_argument(
        "--heat-rate",
        type=_positive,
        default=1.0,
        metavar="F",
        help="heating speed factor; 1 is realistic (hotend 200 C in ~30 s)",
    )
    parser.add_argument(
        "--cool-rate",
        type=_positive,
        default=None,
        metavar="F",
        help="cooling speed factor (default: the --heat-rate value, which keeps "
        "peak temperatures realistic while the whole model runs faster)",
    )
    parser.add_argument(
        "--ambient",
        type=float,
        default=25.0,
        metavar="C",
        help="room temperature in C (default 25)",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the process exit code (2 when the link cannot be taken)."""
    args = parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    settings = ThermalSettings(
        heat_factor=args.heat_rate,
        cool_factor=args.cool_rate or args.heat_rate,
        ambient=args.ambient,
    )
    try:
        link = PtyLink(args.link)
    except LinkError as exc:
        print(f"kybercore.sim.mcu: {exc}", file=sys.stderr)
        return 2
    stop_r, stop_w = os.pipe()
    os.set_blocking(stop_w, False)
    signal.set_wakeup_fd(stop_w)
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda _signum, _frame: None)
    try:
        clock = monotonic_clock()
        firmware = VirtualFirmware(clock, link.write, settings, on_reset=link.discard_buffers)
        log.info("Virtual MCU on %s (link %s)", link.slave_name, args.link)
        serve(link, firmware, clock, stop_r)
        log.info("Stopping virtual MCU on %s", args.link)
    finally:
        link.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
