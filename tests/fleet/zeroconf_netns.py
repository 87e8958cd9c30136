"""A real Moonraker with its own ``[zeroconf]``, browsed by KyberCore, in a network namespace.

Moonraker's zeroconf announces on every interface of the machine (python-zeroconf's
InterfaceChoice.All; no option narrows it), so on the test machine itself it would multicast
on the LAN. A fresh network namespace (``unshare --net``) has a loopback interface and
nothing else: there the announcement and the browse can only meet on loopback.

The parent (:func:`browse_in_netns`) runs this module as ``unshare --net python -m ...``; the
child (:func:`main`) brings loopback up with multicast, starts a virtual printer with
``[zeroconf]``, browses with :func:`kybercore.fleet.discovery.browse` and prints what it
found and what Moonraker says of itself, as one JSON line.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.fleet.discovery import browse
from kybercore.sim.stack import PrinterStack, StackOptions

_ROOT = Path(__file__).resolve().parents[2]
_CHILD_TIMEOUT = 150.0
BROWSE_SECONDS = 3.0


def require_netns() -> None:
    """Skip without network namespaces; fail on CI (``CI=true``), where they must work."""
    reason = ""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        reason = "unshare or ip is not installed"
    else:
        probe = subprocess.run(
            ["unshare", "--net", "ip", "link", "set", "lo", "up"],
            capture_output=True,
            text=True,
            check=False,
        )
        if probe.returncode != 0:
            reason = f"unshare --net failed: {probe.stderr.strip()}"
    if not reason:
        return
    if os.environ.get("CI") == "true":
        pytest.fail(f"network namespaces are required on CI: {reason}")
    pytest.skip(f"no network namespace: {reason}")


def browse_in_netns(data_dir: Path, hostname: str) -> dict[str, Any]:
    """Start a printer with ``[zeroconf]`` and browse for it, both in a new namespace."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(_ROOT / "src"), str(_ROOT)]),
    }
    command = ["unshare", "--net", sys.executable, "-m", __name__, str(data_dir), hostname]
    # unshare execs Python: a SIGTERM on timeout reaches the child, which stops its printer.
    with subprocess.Popen(
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    ) as child:
        try:
            out, err = child.communicate(timeout=_CHILD_TIMEOUT)
        except subprocess.TimeoutExpired:
            child.terminate()
            out, err = child.communicate(timeout=30)
    if child.returncode != 0 or not out.strip():
        raise AssertionError(f"the namespace child failed ({child.returncode}):\n{err}")
    result: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return result


def _loopback_with_multicast() -> None:
    """In a new namespace loopback is down, and multicast has no route without one."""
    for args in (
        ["link", "set", "lo", "up"],
        ["link", "set", "lo", "multicast", "on"],
        ["route", "add", "224.0.0.0/4", "dev", "lo"],
    ):
        subprocess.run(["ip", *args], check=True)


async def _browse_printer(stack: PrinterStack) -> dict[str, Any]:
    async with httpx.AsyncClient(trust_env=False) as http:
        info = (await http.get(f"{stack.url}/server/info")).json()["result"]
    # No interface given: what "Find printers" does by default, here loopback only.
    found = await browse(BROWSE_SECONDS)
    return {
        "port": stack.port,
        "moonraker_version": info["moonraker_version"],
        "found": [dataclasses.asdict(entry) for entry in found],
    }


def main(data_dir: str, hostname: str) -> None:
    """The child, inside the namespace."""
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    _loopback_with_multicast()
    options = StackOptions(name="zeroconf", mdns_hostname=hostname, heat_rate=8.0)
    stack = PrinterStack(options, Path(data_dir))
    try:
        stack.start()
        stack.wait_ready()
        result = asyncio.run(_browse_printer(stack))
    finally:
        stack.stop()
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:3])
