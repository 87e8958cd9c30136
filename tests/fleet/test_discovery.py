"""Finding Moonraker servers over mDNS: the announcement read as Moonraker's [zeroconf]
component writes it, and a real python-zeroconf announcer on loopback found by browsing.

Moonraker's own [zeroconf] announces on every interface of the machine (python-zeroconf's
InterfaceChoice.All, not configurable), which would put multicast on the LAN: it is tested
inside a loopback-only network namespace. The announcer below, in this process, sends what
Moonraker sends, for the tests that need the shared printer and KyberCore's own process.
"""

from __future__ import annotations

import re
import socket
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest
from zeroconf.asyncio import AsyncServiceInfo, AsyncZeroconf

from kybercore.fleet.discovery import SERVICE_TYPE, browse, found_of, slug
from kybercore.sim.stack import PrinterStack
from tests.conftest import MDNS
from tests.fleet.zeroconf_netns import browse_in_netns, require_netns


def moonraker_announcement(name: str, port: int, server: str, **props: str) -> AsyncServiceInfo:
    """What Moonraker's zeroconf component registers (components/zeroconf.py)."""
    properties = {"uuid": "4f1c2d3e5a6b", "https_port": "", "version": "v0.9.3", **props}
    return AsyncServiceInfo(
        SERVICE_TYPE,
        f"{name}.{SERVICE_TYPE}",
        addresses=[socket.inet_aton("127.0.0.1")],
        port=port,
        properties={**properties, "route_prefix": ""},
        server=server,
    )


def test_an_announcement_becomes_an_address_to_add() -> None:
    found = found_of(
        f"Moonraker-4f1c2d3e @ voron.{SERVICE_TYPE}",
        [socket.inet_aton("192.168.1.50")],
        7125,
        "voron.local.",
        {b"uuid": b"4f1c", b"version": b"v0.9.3", b"https_port": b"", b"route_prefix": b""},
    )
    assert found is not None
    assert found.url == "http://192.168.1.50:7125"
    assert found.version == "v0.9.3"
    assert found.suggested_id == "voron"
    assert found.name == "Moonraker-4f1c2d3e @ voron"


def test_https_ipv6_and_a_route_prefix() -> None:
    found = found_of(
        f"M.{SERVICE_TYPE}", [socket.inet_pton(socket.AF_INET6, "fd00::5")], 7125, None,
        {b"https_port": b"7130", b"route_prefix": b"/printer1", b"version": None},
    )  # fmt: skip
    assert found is not None
    assert found.url == "https://[fd00::5]:7130/printer1"
    assert found.suggested_id == "m"
    assert found_of("x", [], 7125, None, {}) is None


@pytest.mark.parametrize(
    ("text", "expected"),
    [("Voron 2.4", "voron-2-4"), ("  ", "printer"), ("A" * 80, "a" * 64), ("MK4_01", "mk4-01")],
)
def test_slug(text: str, expected: str) -> None:
    assert slug(text) == expected


@pytest.fixture
async def announcer() -> AsyncIterator[AsyncZeroconf]:
    zc = AsyncZeroconf(interfaces=[MDNS])
    yield zc
    await zc.async_unregister_all_services()
    await zc.async_close()


async def test_browsing_finds_a_real_moonraker_announced_on_loopback(
    announcer: AsyncZeroconf, printer: PrinterStack, http: httpx.AsyncClient
) -> None:
    port = int(printer.url.rsplit(":", 1)[1])
    await announcer.async_register_service(
        moonraker_announcement("Moonraker-4f1c2d3e", port, "kc-lab.local.")
    )
    found = await browse(2, [MDNS])
    [mine] = [f for f in found if f.port == port]
    assert mine.url == printer.url
    assert mine.suggested_id == "kc-lab"
    # The address found is a working Moonraker.
    answer = await http.get(f"{mine.url}/server/info")
    assert answer.json()["result"]["klippy_state"] == "ready"


@pytest.mark.integration
def test_browsing_finds_moonrakers_own_zeroconf_announcement(
    runtimes: None, tmp_path: Path
) -> None:
    """Moonraker's [zeroconf] itself, not an imitation: in a loopback-only network namespace
    (tests/fleet/zeroconf_netns.py), where its every-interface announcement stays local."""
    require_netns()
    result = browse_in_netns(tmp_path / "printer", "kc-zeroconf")
    [mine] = result["found"]  # the namespace holds this one Moonraker only
    assert mine["host"] == "127.0.0.1"
    assert mine["port"] == result["port"]
    assert mine["url"] == f"http://127.0.0.1:{result['port']}"
    assert mine["version"] == result["moonraker_version"] != ""
    # Moonraker names its instance after its UUID and the host name from [zeroconf].
    assert re.fullmatch(r"[0-9a-f]{32}", mine["uuid"])
    assert mine["name"] == f"Moonraker-{mine['uuid'][:8]} @ kc-zeroconf"
    assert mine["suggested_id"] == "kc-zeroconf"
