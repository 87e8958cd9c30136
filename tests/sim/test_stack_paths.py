"""Virtual printers start wherever their data folder is, and say at once why they did not."""

from __future__ import annotations

from pathlib import Path

import pytest

from kybercore.errors import LaunchError
from kybercore.sim.stack import READY_TIMEOUT, PrinterStack, StackOptions, running_stacks

pytestmark = pytest.mark.integration


def test_printers_in_a_long_folder_start_together(runtimes: None, tmp_path: Path) -> None:
    # A long CI workspace or home: the data folder alone passes the 108-byte socket limit,
    # and printers started together must not race for Klippy's default input pty.
    base = tmp_path / ("a-very-long-folder-name-" * 5)
    assert len(str(base / "p0" / "comms" / "klippy.sock")) > 108
    options = [StackOptions(name=f"p{i}", heat_rate=8.0) for i in range(3)]
    with running_stacks(base, options) as stacks:
        ttys = {stack.comms_dir / "printer" for stack in stacks}
        assert all(tty.is_symlink() for tty in ttys)
        assert len(ttys) == 3
    assert not any(stack.comms_dir.exists() for stack in stacks)


def test_a_klippy_that_dies_at_start_is_reported_at_once(
    runtimes: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Klippy's main thread dies on a socket path it cannot bind, but its logging thread
    # keeps the process alive: the launcher must read the cause, not wait for a timeout.
    unbindable = Path("/tmp") / ("s" * 120)
    monkeypatch.setattr(PrinterStack, "_klippy_socket", property(lambda self: unbindable))
    stack = PrinterStack(StackOptions("dies", heat_rate=8.0), tmp_path / "dies")
    stack.start()
    try:
        with pytest.raises(LaunchError) as error:
            stack.wait_ready(timeout=READY_TIMEOUT)
    finally:
        stack.stop()
    message = error.value.message
    assert "Klippy failed at start" in message
    assert "AF_UNIX path too long" in message
    assert "did not become ready" not in message
