"""The dashboard's "Find printers": the Moonraker servers announcing themselves over mDNS.

Moonraker's ``[zeroconf]`` component registers ``_moonraker._tcp.local.`` with its address,
port and a TXT record (``uuid``, ``version``, ``https_port``, ``route_prefix``). Browsing
lasts a few seconds; what it finds is only a suggestion, added through the same validated
path as a printer typed in by hand.
"""

from __future__ import annotations

import asyncio
import ipaddress
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

from zeroconf import InterfaceChoice, ServiceStateChange
from zeroconf.asyncio import AsyncServiceBrowser, AsyncServiceInfo, AsyncZeroconf

SERVICE_TYPE: Final = "_moonraker._tcp.local."
_SLUG_PART: Final = re.compile(r"[^a-z0-9]+")
_INFO_TIMEOUT_MS: Final = 1500


@dataclass(frozen=True, slots=True)
class Found:
    """A Moonraker that answered: where it is and what it says of itself."""

    name: str
    host: str
    port: int
    url: str
    version: str
    uuid: str
    suggested_id: str


def found_of(
    name: str, addresses: Sequence[bytes], port: int | None, server: str | None,
    properties: dict[bytes, bytes | None],
) -> Found | None:  # fmt: skip
    """A :class:`Found` from a resolved service (pure); None without an address or port."""
    if not addresses or not port:
        return None
    address = ipaddress.ip_address(addresses[0])
    host = f"[{address}]" if address.version == 6 else str(address)
    text = {
        key.decode(errors="replace"): (value or b"").decode(errors="replace")
        for key, value in properties.items()
    }
    https = text.get("https_port", "")
    scheme, shown_port = ("https", int(https)) if https.isdigit() else ("http", port)
    prefix = text.get("route_prefix", "").strip("/")
    instance = name.removesuffix("." + SERVICE_TYPE)
    # Moonraker names its server "<hostname>.local.": the printer's own name on the LAN.
    local = (server or "").removesuffix(".").removesuffix(".local")
    return Found(
        name=instance,
        host=host,
        port=shown_port,
        url=f"{scheme}://{host}:{shown_port}" + (f"/{prefix}" if prefix else ""),
        version=text.get("version", ""),
        uuid=text.get("uuid", ""),
        suggested_id=slug(local or instance),
    )


def slug(text: str) -> str:
    """A printer id from a host or instance name: ``Voron 2.4`` → ``voron-2-4``."""
    value = _SLUG_PART.sub("-", text.lower()).strip("-")[:64]
    return value or "printer"


async def browse(seconds: float, interfaces: Sequence[str] | None = None) -> list[Found]:
    """The Moonraker servers heard within ``seconds``, on ``interfaces`` (IP addresses of
    this machine's interfaces; all of them when None), sorted by name."""
    zc = AsyncZeroconf(interfaces=list(interfaces) if interfaces else InterfaceChoice.All)
    found: dict[str, Found] = {}
    pending: set[asyncio.Task[None]] = set()

    async def resolve(name: str) -> None:
        info = AsyncServiceInfo(SERVICE_TYPE, name)
        if await info.async_request(zc.zeroconf, _INFO_TIMEOUT_MS):
            entry = found_of(name, info.addresses, info.port, info.server, info.properties)
            if entry is not None:
                found[name] = entry

    def on_change(**event: Any) -> None:
        if event["state_change"] in (ServiceStateChange.Added, ServiceStateChange.Updated):
            task = asyncio.ensure_future(resolve(event["name"]))
            pending.add(task)
            task.add_done_callback(pending.discard)

    browser = AsyncServiceBrowser(zc.zeroconf, SERVICE_TYPE, handlers=[on_change])
    try:
        await asyncio.sleep(seconds)  # mDNS has no "done": answers come while we listen
        if pending:
            await asyncio.wait(pending, timeout=_INFO_TIMEOUT_MS / 1000)
    finally:
        for task in pending:
            task.cancel()
        await browser.async_cancel()
        await zc.async_close()
    return sorted(found.values(), key=lambda f: f.name)
