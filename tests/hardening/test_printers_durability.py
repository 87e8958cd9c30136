"""printers.json survives writers killed with SIGKILL at random points, and two processes
(a real ``kybercore serve`` and the ``kybercore printers`` CLI) writing at once lose nothing.

The torture test forks a child that mutates printers.json through :class:`PrinterRegistry`
forever, announcing every operation on a pipe before it starts (``B``) and after the
registry returned (``A``: acknowledged). The parent waits until it has begun 1-3 writes and
SIGKILLs it 0-30 ms later, then checks that the file validates and equals the acknowledged
state, or that state plus the one operation in flight when the kill landed: nothing else.
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from kybercore.registry.format import backup_path
from kybercore.registry.models import PrinterCreate, PrinterUpdate
from kybercore.registry.store import PrinterRegistry, read_printers
from kybercore.sim.stack import free_port
from tests.helpers import KyberCoreServer

ROUNDS = 250  # the issue asks for at least 200
MAX_KILL_DELAY = 0.030
BEGIN_WITHIN = 30.0
"""Deadline for a writer to begin its first writes (idle: a few ms)."""


def _url(n: int) -> str:
    """Printer ``n``'s Moonraker, one per printer: the discard port of a loopback address of
    its own (nothing listens, nothing leaves loopback)."""
    return f"http://127.0.{n // 200}.{n % 200 + 1}:9"


State = dict[str, str]
"""printer id -> notes (every write stamps the printer's notes with a unique value)."""


def _child(path: Path, round_no: int, ack_fd: int, seed: int) -> None:
    """Mutate printers.json forever; never returns (runs in the forked child)."""
    rng = random.Random(seed)
    registry = PrinterRegistry(path)
    registry.reload()
    step = 0
    while True:
        step += 1
        stamp = f"r{round_no}s{step}"
        ids = [p.id for p in registry.printers]
        roll = rng.random()
        if len(ids) < 3 or (roll < 0.35 and len(ids) < 12):
            op = f"add {stamp} {stamp}"
            os.write(ack_fd, f"B {op}\n".encode())
            url = f"http://{stamp}.invalid:9"  # one Moonraker per printer; never dialled
            registry.add(PrinterCreate(id=stamp, name=stamp, moonraker_url=url, notes=stamp))
        elif roll < 0.5:
            victim = rng.choice(ids)
            op = f"rm {victim} -"
            os.write(ack_fd, f"B {op}\n".encode())
            registry.remove(victim)
        else:
            victim = rng.choice(ids)
            op = f"upd {victim} {stamp}"
            os.write(ack_fd, f"B {op}\n".encode())
            registry.update(victim, PrinterUpdate(notes=stamp))
        os.write(ack_fd, f"A {op}\n".encode())


def _apply(state: State, op: str) -> State:
    kind, printer_id, notes = op.split(" ")
    after = dict(state)
    if kind == "rm":
        del after[printer_id]
    else:
        after[printer_id] = notes
    return after


def _on_disk(path: Path) -> State:
    # read_printers raises ConfigError for a half-written or invalid file: that fails the test.
    return {p.id: p.notes for p in read_printers(path)}


def _kill_after(path: Path, round_no: int, begun: int, delay: float) -> list[str]:
    """Fork a writer; once it has begun ``begun`` writes, SIGKILL it ``delay`` seconds later
    (a random point of the write in flight); return the lines it wrote."""
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never return into pytest
        try:
            os.close(read_fd)
            _child(path, round_no, write_fd, seed=round_no)
        finally:
            os._exit(3)
    os.close(write_fd)
    received = b""
    deadline = time.monotonic() + BEGIN_WITHIN
    while sum(line.startswith(b"B ") for line in received.splitlines()) < begun:
        # Wait for the writer's next line (each is one write to the pipe), deadline above.
        ready, _, _ = select.select([read_fd], [], [], max(0.0, deadline - time.monotonic()))
        chunk = os.read(read_fd, 65536) if ready else b""
        if not chunk:
            os.kill(pid, signal.SIGKILL)
            raise AssertionError(f"the writer did not begin {begun} writes: {received!r}")
        received += chunk
    time.sleep(delay)  # fault injection: the kill lands at a random point of the write
    os.kill(pid, signal.SIGKILL)
    _, status = os.waitpid(pid, 0)
    assert os.WIFSIGNALED(status), f"writer exited by itself (status {status}): it crashed"
    chunks = [received]
    while chunk := os.read(read_fd, 65536):
        chunks.append(chunk)
    os.close(read_fd)
    return b"".join(chunks).decode().splitlines()


def test_sigkilled_writers_never_corrupt_or_lose_acknowledged_writes(tmp_path: Path) -> None:
    path = tmp_path / "printers.json"
    rng = random.Random(8)
    state: State = {}
    acknowledged = in_flight_kills = in_flight_landed = 0
    started = time.monotonic()
    for round_no in range(ROUNDS):
        lines = _kill_after(path, round_no, rng.randint(1, 3), rng.uniform(0, MAX_KILL_DELAY))
        pending: str | None = None
        for line in lines:
            mark, op = line.split(" ", 1)
            if mark == "B":
                pending = op
            else:
                assert op == pending, f"round {round_no}: ack without begin: {lines}"
                state, pending = _apply(state, op), None
                acknowledged += 1
        on_disk = _on_disk(path)
        if pending is None:
            assert on_disk == state, f"round {round_no}: an acknowledged write is missing"
        else:
            in_flight_kills += 1
            landed = _apply(state, pending)
            assert on_disk in (state, landed), (
                f"round {round_no}: killed during '{pending}', the file holds neither the "
                f"acknowledged state nor that write:\n{on_disk}\n{state}"
            )
            if on_disk == landed:
                in_flight_landed += 1
            state = on_disk  # the next writer starts from what is really there
        if backup_path(path).exists():
            read_printers(backup_path(path))  # the backup is whole too
    elapsed = time.monotonic() - started
    print(
        f"\n{ROUNDS} SIGKILLs in {elapsed:.1f} s: {acknowledged} acknowledged writes, "
        f"{in_flight_kills} kills with a write in flight ({in_flight_landed} of them had "
        f"already replaced the file), {len(state)} printers at the end"
    )
    # The test only means something if kills really land mid-write, and writes get done:
    # every writer began 1-3 writes before its kill, whatever the machine's speed.
    assert acknowledged >= ROUNDS // 4
    assert in_flight_kills >= ROUNDS // 4
    # Temp files of killed writers are cleaned by the next write, not left to pile up: at
    # most the last writer's are left, its new file and, if the kill landed while the old
    # file was being kept as the backup, the backup's hard link (``.printers.json.bak.tmp``).
    leftovers = sorted(p.name for p in tmp_path.glob(".printers.json.*.tmp"))
    new_files = [name for name in leftovers if name != ".printers.json.bak.tmp"]
    assert len(new_files) <= 1, leftovers


# -- server and CLI writing at once ----------------------------------------------------

SERVER_ADDS = 30
CLI_ADDS = 8
CLI_EDITS = 4


@pytest.fixture
def lone_server(tmp_path: Path) -> Iterator[KyberCoreServer]:
    """A real `kybercore serve` on its own printers.json (printers unreachable on purpose)."""
    path = tmp_path / "printers.json"
    path.write_text(json.dumps({"version": 1, "printers": []}))
    server = KyberCoreServer(path, free_port())
    server.start()
    yield server
    server.stop()


def _cli(path: Path, *args: str) -> subprocess.Popen[bytes]:
    command = [sys.executable, "-m", "kybercore", "printers", "--printers-file", str(path), *args]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


async def test_server_and_cli_writing_at_once_lose_nothing(lone_server: KyberCoreServer) -> None:
    path = lone_server.printers_file
    seed = [f"seed-{n}" for n in range(CLI_EDITS)]
    async with httpx.AsyncClient(base_url=lone_server.url, timeout=30) as api:
        for n, printer_id in enumerate(seed):
            body = {"id": printer_id, "name": printer_id, "moonraker_url": _url(n)}
            assert (await api.post("/api/printers", json=body)).status_code == 201
        # The CLI processes start first (they take ~1 s to import) and overlap the API writes.
        cli = [
            _cli(path, "add", f"CLI {n}", "--id", f"cli-{n}", "--url", _url(1000 + n))
            for n in range(CLI_ADDS)
        ]
        cli += [_cli(path, "edit", pid, "--notes", f"cli-edit-{pid}") for pid in seed]

        # The server keeps writing until every CLI process is done: the writes overlap.
        n = 0
        while n < SERVER_ADDS or any(proc.poll() is None for proc in cli):
            body = {"id": f"api-{n}", "name": f"API {n}", "moonraker_url": _url(2000 + n)}
            answer = await api.post("/api/printers", json=body)
            assert answer.status_code == 201, answer.text
            if n < len(seed):
                edit = await api.patch(f"/api/printers/{seed[n]}", json={"location": "api"})
                assert edit.status_code == 200, edit.text
            n += 1
        for proc in cli:
            out, err = await asyncio.to_thread(proc.communicate, timeout=60)
            assert proc.returncode == 0, (out + err).decode()
        print(f"\n{n} API writes overlapped {len(cli)} CLI writes")

        expected = (
            set(seed) | {f"api-{i}" for i in range(n)} | {f"cli-{n}" for n in range(CLI_ADDS)}
        )
        on_disk = {p.id: p for p in read_printers(path)}
        assert set(on_disk) == expected
        for printer_id in seed:  # both processes edited these: both edits are kept
            assert on_disk[printer_id].notes == f"cli-edit-{printer_id}"
            assert on_disk[printer_id].location == "api"
        # The server notices the CLI's writes on disk and serves the merged fleet.
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            served = {v["id"]: v for v in (await api.get("/api/printers")).json()}
            if set(served) == expected and all(served[p]["notes"] == f"cli-edit-{p}" for p in seed):
                break
            await asyncio.sleep(0.1)  # poll: wait for the merged fleet, deadline above
        else:
            raise AssertionError(f"the server did not pick up the CLI's writes: {sorted(served)}")
