"""Why Moonraker could not be reached, in a sentence a person can act on.

A connection fails deep inside a library, and the exception that reaches KyberCore wraps
the one that names the cause: httpx's ``ConnectError`` wraps anyio's "All connection
attempts failed", which wraps the socket's ``[Errno 113] Connect call failed``, or a group
of them when a name has several addresses. :func:`connect_problem` looks through all of it.
"""

from __future__ import annotations

import errno
import re
import socket
import ssl
from collections.abc import Iterator
from typing import Final

# asyncio joins the errors of several addresses into one message: "Multiple exceptions:
# [Errno 113] Connect call failed (...), [Errno 113] ...". The numbers are all that is left.
_ERRNO_IN_TEXT: Final = re.compile(r"\[Errno (-?\d+)\]")
# "[SSL: CERTIFICATE_VERIFY_FAILED] certificate verify failed: ... (_ssl.c:1006)"
_SSL_NOISE: Final = re.compile(r"^\[SSL: \w+\] |\s*\(_ssl\.c:\d+\)$")
_REFUSED: Final = frozenset({errno.ECONNREFUSED})
_NO_ROUTE: Final = frozenset({errno.EHOSTUNREACH, errno.EHOSTDOWN})
_NO_NETWORK: Final = frozenset({errno.ENETUNREACH, errno.ENETDOWN})
_TIMED_OUT: Final = frozenset({errno.ETIMEDOUT})
_RESET: Final = frozenset({errno.ECONNRESET, errno.ECONNABORTED, errno.EPIPE})


def connect_problem(exc: BaseException, where: str, timeout: float | None = None) -> str:
    """What a failed connection to Moonraker at ``where`` means, and what to do about it.

    ``timeout`` is how long the connection was given, when the caller knows it.
    """
    causes = list(_causes(exc))
    codes = {c.errno for c in causes if isinstance(c, OSError) and isinstance(c.errno, int)}
    codes |= {int(n) for c in causes for n in _ERRNO_IN_TEXT.findall(str(c))}
    text = " ".join(str(c) for c in causes).lower()
    tls = next((c for c in causes if isinstance(c, ssl.SSLError)), None)
    # TLS first: ssl errors are OSErrors with numbers of their own.
    if tls is not None:
        return (
            f"the TLS (https/wss) handshake with {where} failed ({_tls_reason(tls)}). Use http:// "
            "for a Moonraker without TLS; with TLS, check the printer's certificate."
        )
    if any(isinstance(c, socket.gaierror) for c in causes) or "name resolution" in text:
        return (
            f"the host name in {where} cannot be resolved. Check the printer's URL or use "
            "its IP address."
        )
    if codes & _REFUSED or any(isinstance(c, ConnectionRefusedError) for c in causes):
        return f"connection refused by {where}. Is Moonraker running, and is the port right?"
    if codes & _NO_ROUTE:
        return (
            f"no route to {where}: the host is switched off, asleep or not on this network. "
            "Check that the printer is on and its address is right."
        )
    if codes & _NO_NETWORK:
        return (
            f"the network of {where} is unreachable from this computer. Check this "
            "computer's network connection and the printer's address."
        )
    if codes & _TIMED_OUT or any(isinstance(c, TimeoutError) for c in causes):
        within = f" (nothing within {timeout:g} s)" if timeout else ""
        return (
            f"timed out while connecting to {where}{within}: the printer may be off, or a "
            "firewall drops the connection. Check its address and network."
        )
    if codes & _RESET or any(isinstance(c, ConnectionResetError) for c in causes):
        return f"the connection to {where} was reset (is Moonraker restarting?). Retry later."
    return f"cannot reach Moonraker at {where} ({exc or type(exc).__name__}). Retry later."


def connection_refused(exc: BaseException) -> bool:
    """Whether ``exc`` is a refused connection: the host answered, nothing listens there."""
    causes = list(_causes(exc))
    if any(isinstance(c, ConnectionRefusedError) for c in causes):
        return True
    return any(str(errno.ECONNREFUSED) in _ERRNO_IN_TEXT.findall(str(c)) for c in causes)


def _tls_reason(error: ssl.SSLError) -> str:
    """OpenSSL's reason in words: "certificate verify failed: self-signed certificate"."""
    verify = getattr(error, "verify_message", None)
    if verify:
        return f"certificate verify failed: {verify}"
    reason = getattr(error, "reason", None)  # set by OpenSSL, absent on a hand-made error
    if reason:
        return str(reason).lower().replace("_", " ")
    return _SSL_NOISE.sub("", error.strerror or str(error)).strip()


def _causes(exc: BaseException) -> Iterator[BaseException]:
    """``exc``, what it was raised from, and every member of an exception group, once."""
    seen: set[int] = set()
    todo = [exc]
    while todo:
        current = todo.pop()
        if id(current) in seen:
            continue
        seen.add(id(current))
        yield current
        if isinstance(current, BaseExceptionGroup):
            todo.extend(current.exceptions)
        for linked in (current.__cause__, current.__context__):
            if linked is not None:
                todo.append(linked)
