"""The benchmark's child processes: start them, talk to them in JSON lines, stop them by PID,
and read what the kernel says they cost (``/proc/<pid>``)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import IO, Any

import orjson

_TICKS_PER_SECOND = os.sysconf("SC_CLK_TCK")
STOP_TIMEOUT = 10.0


def compiled(src: Path | None) -> bool:
    """Whether ``kybercore`` under ``src`` (None: the installed one) runs its hot path
    compiled (``kybercore/native.py``): a figure means little without it."""
    env = {**os.environ, "PYTHONPATH": str(src)} if src else None
    probe = "from kybercore import native; print(native.STATE.active)"
    done = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=120
    )
    return done.stdout.strip() == "True"


def free_port() -> int:
    """A loopback port nobody listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextlib.asynccontextmanager
async def child(
    *args: str,
    log: IO[bytes] | None = None,
    pipe_stdin: bool = False,
    env: dict[str, str] | None = None,
) -> AsyncIterator[asyncio.subprocess.Process]:
    """``python <args>`` for the duration of the block; stopped by its PID afterwards.

    With ``log``, stdout and stderr go there; otherwise stdout is a pipe for JSON lines.
    """
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        *args,
        stdin=asyncio.subprocess.PIPE if pipe_stdin else asyncio.subprocess.DEVNULL,
        stdout=log if log is not None else asyncio.subprocess.PIPE,
        stderr=log if log is not None else None,
        env=env,
    )
    try:
        yield process
    finally:
        await stop(process)


async def stop(process: asyncio.subprocess.Process) -> None:
    """SIGTERM, then SIGKILL if it lingers; only ever this one PID."""
    if process.returncode is not None:
        return
    if process.stdin is not None:
        process.stdin.close()
    with contextlib.suppress(ProcessLookupError):
        process.terminate()
    try:
        await asyncio.wait_for(process.wait(), STOP_TIMEOUT)
    except TimeoutError:
        with contextlib.suppress(ProcessLookupError):
            process.kill()
        await process.wait()


async def read_json_line(process: asyncio.subprocess.Process, timeout: float) -> Any:
    """The next JSON line the child prints; fails if it exits or stays silent."""
    assert process.stdout is not None
    line = await asyncio.wait_for(process.stdout.readline(), timeout)
    if not line:
        raise RuntimeError(f"process {process.pid} exited (code {await process.wait()})")
    return orjson.loads(line)


async def command(process: asyncio.subprocess.Process, line: str, timeout: float) -> Any:
    """Send one command line on the child's stdin and read its JSON answer."""
    assert process.stdin is not None
    process.stdin.write(line.encode() + b"\n")
    await process.stdin.drain()
    return await read_json_line(process, timeout)


def rss_kib(pid: int) -> int:
    """Resident memory (``VmRSS``) in KiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for process {pid}")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time the process has used so far."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    # Fields after the command name, which may itself contain spaces and parentheses.
    fields = stat[stat.rindex(")") + 2 :].split()
    utime, stime = int(fields[11]), int(fields[12])
    return (utime + stime) / _TICKS_PER_SECOND
