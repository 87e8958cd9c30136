"""A site behind a NATS leaf node: its workers connect to the site's own nats-server, linked
to the hub, and use the hub's JetStream domain, named in their address
(``nats://site-leaf:4222?js_domain=hub``), for the registry and job files, and for their
leases too unless the leaf node has JetStream of its own and they keep them there
(``--local-leases``), so that a cut from the hub leaves the site's printers held. Real
nats-servers (a hub and a leaf node), real workers, fronts (on the hub, at the site) and
printers."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import io
import json
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import nats.errors
import pytest

from kybercore.errors import BrokerUnavailable, ConfigError
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.scale.broker import LocalServer, connect, jetstream, jetstream_domain, servers
from kybercore.scale.buckets import NO_JETSTREAM, key_value, wrong_revision
from kybercore.scale.jobfiles import JobFileBucket
from kybercore.scale.last_read import FILE
from kybercore.scale.leases import SLOTS_BUCKET
from kybercore.scale.slots import slot_key
from kybercore.sim.stack import PrinterStack, free_port
from tests.cable import Cable
from tests.helpers import KyberCoreServer, wait_for, wait_until
from tests.scale.cluster import SETTLE, SLOTS, TTL, WorkerProcess

DOMAIN = "hub"
LINKED_WITHIN = 30.0
"""A leaf node links to its hub within a second; a busy machine may take longer."""


@contextlib.contextmanager
def linked_servers(
    folder: Path, leaf_domain: str | None
) -> Iterator[tuple[LocalServer, LocalServer, Cable]]:
    """A hub with JetStream in domain ``hub``, and a leaf node linked to it through a
    :class:`Cable`: with JetStream of its own in ``leaf_domain``, or none."""
    link = free_port()
    hub_conf = folder / "hub.conf"
    # no_advertise: else the leaf node learns the hub's own address and reconnects past the
    # cable once it is cut.
    hub_conf.write_text(
        f"jetstream {{ domain: {DOMAIN} }}\n"
        f"leafnodes {{ listen: 127.0.0.1:{link}, no_advertise: true }}\n"
    )
    cable = Cable(link)
    leaf_conf = folder / "leaf.conf"
    leaf_conf.write_text(
        (f"jetstream {{ domain: {leaf_domain} }}\n" if leaf_domain else "")
        + f'leafnodes {{ remotes: [{{ url: "nats-leaf://127.0.0.1:{cable.port}" }}] }}\n'
    )
    hub = LocalServer(folder / "hub", "-c", str(hub_conf))
    leaf = LocalServer(folder / "leaf", "-c", str(leaf_conf), jetstream=leaf_domain is not None)
    hub.start()
    try:
        cable.start()
        leaf.start()
        yield hub, leaf, cable
    finally:
        leaf.close()
        cable.close()
        hub.close()


@pytest.fixture
def hub_and_leaf(tmp_path: Path) -> Iterator[tuple[LocalServer, LocalServer]]:
    """A hub, and a leaf node without JetStream (a site's workers use the hub's)."""
    with linked_servers(tmp_path, None) as (hub, leaf, _):
        yield hub, leaf


@pytest.fixture
def hub_and_site_leaf(tmp_path: Path) -> Iterator[tuple[LocalServer, LocalServer, Cable]]:
    """A hub, and a leaf node with JetStream of its own, in domain ``lab-b``, and the cable
    between them."""
    with linked_servers(tmp_path, "lab-b") as linked_:
        yield linked_


def site_url(leaf: LocalServer) -> str:
    return f"{leaf.url}?js_domain={DOMAIN}"


async def linked(url: str) -> float:
    """Wait until the hub's JetStream answers through ``url``; the seconds it took."""

    async def answers() -> bool:
        try:
            await nc.jetstream().account_info()
        except (nats.errors.Error, TimeoutError):
            return False
        return True

    nc = await connect(url, "probe")
    try:
        return await wait_for(answers, LINKED_WITHIN, "the leaf node linked to its hub")
    finally:
        await nc.close()


def test_the_domain_is_read_from_the_address_and_nothing_else_is_taken() -> None:
    assert jetstream_domain("nats://a:4222,nats://b:4222?js_domain=site-hub_1") == "site-hub_1"
    assert servers("nats://a:4222,nats://b:4222?js_domain=hub") == [
        "nats://a:4222",
        "nats://b:4222",
    ]
    assert jetstream_domain("nats://a:4222") is None
    for wrong in ("nats://a?domain=hub", "nats://a?js_domain=", "nats://a?js_domain=a.b"):
        with pytest.raises(ConfigError, match=r"\?js_domain=<the hub's JetStream domain>"):
            jetstream_domain(wrong)


async def test_buckets_written_through_a_leaf_node_are_the_hubs(
    hub_and_leaf: tuple[LocalServer, LocalServer],
) -> None:
    hub, leaf = hub_and_leaf
    await linked(site_url(leaf))
    site = await connect(site_url(leaf), "site")
    central = await connect(hub.url, "central")
    try:
        kv = await key_value(site.jetstream(), "kc_leaf_test", history=1)
        revision = await kv.create("s1", b"w1")
        # A compare-and-set through the leaf: taken on the right revision, refused on an old one.
        await kv.update("s1", b"w1 again", last=revision)
        with pytest.raises(Exception) as stale:  # noqa: PT011 (nats-py's error for a stale CAS)
            await kv.update("s1", b"w2", last=revision)
        assert wrong_revision(stale.value)
        hub_kv = await key_value(central.jetstream(), "kc_leaf_test")
        assert (await hub_kv.get("s1")).value == b"w1 again"
        # A job file a site's worker shares is the hub's too.
        content = b"G28\nG1 X10\n" * 5000
        sha256 = hashlib.sha256(content).hexdigest()
        await JobFileBucket(site).share(sha256, io.BytesIO(content), "part.gcode")
        copy = io.BytesIO()
        await JobFileBucket(central).fetch(sha256, copy)
        assert copy.getvalue() == content
        # Without the domain, a leaf node has no JetStream: said, with what to do.
        lost = await connect(leaf.url, "no domain")
        try:
            with pytest.raises(BrokerUnavailable) as said:
                await key_value(lost.jetstream(), "kc_leaf_test")
            assert said.value.message == NO_JETSTREAM
        finally:
            await lost.close()
    finally:
        await site.close()
        await central.close()


@contextlib.contextmanager
def site_lab_b(
    hub: LocalServer,
    leaf: LocalServer,
    stacks: list[PrinterStack],
    folder: Path,
    *args: str,
    front_at: str | None = None,
) -> Iterator[tuple[KyberCoreServer, WorkerProcess]]:
    """``stacks`` as site lab-b's printers: a front on the hub (or at ``front_at``), and the
    site's worker b1 on its leaf node (``args``: more of its options); yields once b1 holds
    every slot of the site and the front shows every printer fresh."""
    printers = [
        PrinterConfig(id=s.options.name, name=s.options.name, site="lab-b", moonraker_url=s.url)
        for s in stacks
    ]
    write_printers(folder / "printers.json", printers)
    # What finds no JetStream stops at once: the leaf node must be linked first.
    print(f"leaf node linked in {asyncio.run(linked(site_url(leaf))):.2f} s")
    front = KyberCoreServer(
        folder / "printers.json", free_port(), "--nats", front_at or hub.url,
        "--slots", str(SLOTS), "--lease-ttl", str(TTL), command="front",
    )  # fmt: skip
    front.start()
    try:
        b1 = WorkerProcess("b1", site_url(leaf), folder, "--site", "lab-b", *args)
        try:
            wait_until(lambda: len(b1.owned()) == SLOTS, SETTLE, "b1 owns lab-b's slots")
            wait_until(lambda: fresh(front) == len(stacks), 60, "every printer fresh")
            yield front, b1
        finally:
            b1.stop()
    finally:
        front.stop()


def fresh(front: KyberCoreServer) -> int:
    """How many printers the front shows online and ready, reported by a live owner."""
    views = httpx.get(f"{front.url}/api/printers", timeout=10).json()
    return sum(v["connection"] == "online" and v["klippy_state"] == "ready" for v in views)


def firmware(front: KyberCoreServer, printer_id: str) -> bool:
    """Whether an M115 sent through the front came back from the printer."""
    answer = httpx.post(
        f"{front.url}/api/printers/{printer_id}/gcode", json={"script": "M115"}, timeout=30
    )
    assert answer.status_code == 200, answer.text
    return any("FIRMWARE_NAME" in line for line in answer.json()["response"])


def test_a_site_worker_on_a_leaf_node_holds_and_drives_its_printers(
    hub_and_leaf: tuple[LocalServer, LocalServer],
    fleet_stacks: list[PrinterStack],
    tmp_path: Path,
) -> None:
    # Its leases are written through the leaf node: it holds every slot of its site, and
    # the front on the hub shows its printers and drives them.
    with site_lab_b(*hub_and_leaf, fleet_stacks, tmp_path) as (front, _):
        assert firmware(front, fleet_stacks[0].options.name)


@pytest.fixture
def site_on_its_own(
    hub_and_site_leaf: tuple[LocalServer, LocalServer, Cable],
    fleet_stacks: list[PrinterStack],
    tmp_path: Path,
) -> Iterator[tuple[KyberCoreServer, WorkerProcess]]:
    """Site lab-b as it rides through cuts: its worker with ``--local-leases`` and its own
    front, both on its leaf node (the registry, the dispatcher's lease and the job files at
    the hub through the leaf; the site's leases, patches and commands at the leaf)."""
    hub, leaf, _ = hub_and_site_leaf
    with site_lab_b(
        hub, leaf, fleet_stacks, tmp_path, "--local-leases", front_at=site_url(leaf)
    ) as started:
        yield started


def test_a_front_at_the_site_drives_its_printers_through_a_cut_from_the_hub(
    site_on_its_own: tuple[KyberCoreServer, WorkerProcess],
    hub_and_site_leaf: tuple[LocalServer, LocalServer, Cable],
    fleet_stacks: list[PrinterStack],
) -> None:
    front, worker = site_on_its_own
    _, leaf, cable = hub_and_site_leaf
    printer = fleet_stacks[0].options.name
    assert firmware(front, printer)
    with cut_from_the_hub(leaf, cable) as two_ttls_passed:
        # Cut off from the hub for two TTLs (the worker renewing its leases at the leaf
        # node meanwhile), the site still sees and drives its own printers.
        two_ttls_passed()
        assert fresh(front) == len(fleet_stacks)
        assert firmware(front, printer)
        assert len(worker.owned()) == SLOTS


@contextlib.contextmanager
def cut_from_the_hub(leaf: LocalServer, cable: Cable) -> Iterator[Callable[[], None]]:
    """Cut ``cable``, the leaf node's line to the hub; yields a wait for two TTLs of lease
    renewals (one every TTL/3) counted from the cut, read in the leaf node's own
    ``kc_slots`` on one connection held meanwhile."""
    with asyncio.Runner() as runner:
        nc = runner.run(connect(leaf.url, "reader"))
        try:
            kv = runner.run(jetstream(nc, local=True).key_value(SLOTS_BUCKET))
            key = slot_key(0, "lab-b")
            seen = {runner.run(kv.get(key)).revision}

            def renewed_for_two_ttls() -> bool:
                seen.add(runner.run(kv.get(key)).revision)
                return len(seen) > round(2 * TTL / (TTL / 3))

            cable.cut()
            yield lambda: wait_until(renewed_for_two_ttls, SETTLE, "renewals for 2 TTLs")
        finally:
            runner.run(nc.close())


def test_a_site_cut_off_from_the_hub_keeps_its_printers_and_the_hub_says_so(
    hub_and_site_leaf: tuple[LocalServer, LocalServer, Cable],
    fleet_stacks: list[PrinterStack],
    tmp_path: Path,
) -> None:
    hub, leaf, cable = hub_and_site_leaf
    with (
        site_lab_b(hub, leaf, fleet_stacks, tmp_path, "--local-leases") as (front, worker),
        cut_from_the_hub(leaf, cable) as two_ttls_passed,
    ):
        # The hub's side: the site's printers stale, saying the site may be cut off, and
        # their commands refused at once, nothing sent.
        wait_until(
            lambda: said_stale(front) == len(fleet_stacks), SETTLE, "the site's printers stale"
        )
        printer = fleet_stacks[1].options.name
        refused = httpx.post(
            f"{front.url}/api/printers/{printer}/gcode", json={"script": "M115"}, timeout=30
        )
        assert refused.status_code == 503, refused.text
        assert refused.json()["error"]["code"] == "owner_moving"
        assert "site is cut off" in refused.json()["error"]["message"]
        # The site's side: its worker renews its leases at its own leaf node; past two TTLs
        # it still holds every slot, and so every printer.
        two_ttls_passed()
        assert len(worker.owned()) == SLOTS
        # The line mended: the hub has the site's printers again, from the same owner.
        cable.mend()
        wait_until(lambda: fresh(front) == len(fleet_stacks), 60, "every printer fresh again")
        assert firmware(front, printer)
        drops = [e for e in map(json.loads, worker.leases_log.read_text().splitlines())
                 if e["ev"] != "own"]  # fmt: skip
        assert drops == []


def test_a_site_worker_restarted_while_cut_off_holds_the_printers_it_read_last(
    site_on_its_own: tuple[KyberCoreServer, WorkerProcess],
    hub_and_site_leaf: tuple[LocalServer, LocalServer, Cable],
    fleet_stacks: list[PrinterStack],
    tmp_path: Path,
) -> None:
    # The registry is at the hub: a worker restarted during a cut starts on the printers
    # it read last (kept in its folder), and follows the registry once the line is mended.
    front, worker = site_on_its_own
    _, leaf, cable = hub_and_site_leaf
    assert (worker.folder / FILE).exists()
    cable.cut()
    worker.stop()  # hands its slots back at the leaf node
    again = WorkerProcess("b1", site_url(leaf), tmp_path, "--site", "lab-b", "--local-leases")
    said = again.folder / "worker.log"
    try:
        wait_until(lambda: len(again.owned()) == SLOTS, SETTLE, "b1 owns lab-b's slots again")
        wait_until(lambda: fresh(front) == len(fleet_stacks), 60, "every printer fresh")
        assert firmware(front, fleet_stacks[0].options.name)
        assert f"starting on the {len(fleet_stacks)} printers of site 'lab-b'" in said.read_text()
        cable.mend()
        wait_until(
            lambda: "registry answers again" in said.read_text(), SETTLE,
            "b1 to follow the registry again",
        )  # fmt: skip
        assert fresh(front) == len(fleet_stacks)
    finally:
        again.stop()


def said_stale(front: KyberCoreServer) -> int:
    """How many printers the front shows stale, saying their site may be cut off."""
    views = httpx.get(f"{front.url}/api/printers", timeout=10).json()
    return sum(
        v["connection"] == "stale" and "site 'lab-b' may be cut off" in v["connection_error"]
        for v in views
    )


def test_a_worker_on_a_leaf_node_without_the_domain_says_what_to_add(
    hub_and_leaf: tuple[LocalServer, LocalServer], tmp_path: Path
) -> None:
    _, leaf = hub_and_leaf
    run = subprocess.run(
        [sys.executable, "-m", "kybercore", "ingest", "--nats", leaf.url, "--dir", str(tmp_path)],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    said = run.stderr + run.stdout
    assert run.returncode != 0
    assert "?js_domain=" in said, said
    assert "Traceback" not in said
    assert "setup plugin" not in said  # the worker's log is about the worker
