"""The names this server answers to: the defence against DNS rebinding.

A page on ``evil.example`` can make its own name resolve to this server; the browser then
treats KyberCore as part of that page's origin (``Origin`` and ``Host`` agree), so an
origin check alone lets it pause printers or send G-code. The ``Host`` header still says
``evil.example``, so only known names are served:

- ``localhost`` and the address or name the server is bound to;
- names given with ``--allowed-host`` / ``$KYBERCORE_ALLOWED_HOSTS`` (a reverse proxy's
  name, a LAN name such as ``printers.lan``);
- any IP address: a browser sends an IP as Host only for a page loaded from that very
  address, and an address cannot be rebound.

The port is not compared: behind a proxy, Host carries the proxy's port.
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Iterable
from typing import Final

from kybercore.errors import ConfigError

_NAME: Final = re.compile(r"[a-z0-9_-]+(\.[a-z0-9_-]+)*")


def host_name(host: str) -> str | None:
    """The name or IP in a Host header (no port, lower case, no final dot); None when it
    is not a plain host[:port]."""
    host = host.strip().lower()
    if host.startswith("["):
        literal, closed, rest = host[1:].partition("]")
        port_ok = not rest or (rest.startswith(":") and rest[1:].isdigit())
        return literal if closed and port_ok and _is_ip(literal) else None
    name, colon, port = host.rpartition(":")
    if not colon:
        name = port
    elif not port.isdigit():
        return None
    name = name.rstrip(".")
    return name if _NAME.fullmatch(name) else None


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class HostAllowlist:
    """The Host names this server serves (any IP address is served too)."""

    def __init__(self, bind: str = "127.0.0.1", names: Iterable[str] = ()) -> None:
        """``bind``: the address or name the server listens on; ``names``: more names
        (ConfigError for one that is not a host name)."""
        allowed = {"localhost"}
        for name in names:
            normal = host_name(name)
            if normal is None:
                raise ConfigError(
                    f"--allowed-host '{name}' is not a host name: give the name (or IP) "
                    "browsers use to reach KyberCore, e.g. printers.lan."
                )
            allowed.add(normal)
        bound = host_name(bind)
        if bound is not None:
            allowed.add(bound)
        self.names: frozenset[str] = frozenset(allowed)

    def allows(self, host: str | None) -> bool:
        """Whether a request with this Host header is for us; no Host is not a browser's."""
        if host is None:
            return True
        name = host_name(host)
        return name is not None and (name in self.names or _is_ip(name))
