"""Talking to a running KyberCore over its REST API, for the commands that act on the
live queue and printers (``kybercore jobs …``, ``kybercore printers clear|hold|release``).

Those need the server: it holds the live printer state a job is checked against, and it
tells every open dashboard about the change. printers.json and tokens.json, by contrast,
are files the CLI edits itself.

An error answer becomes a :class:`RemoteError` carrying the server's message and its
reasons; :func:`remote_errors` prints it as one red ``Error:`` line (plus the reasons) and
exits 2 for a request the server found invalid, 1 for anything else.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, Final

from rich.text import Text

from kybercore.cli.output import err, fail
from kybercore.errors import KyberCoreError

if TYPE_CHECKING:
    import httpx

DEFAULT_URL: Final = "http://127.0.0.1:8000"


class RemoteError(KyberCoreError):
    """The server refused a request; ``status`` and ``code`` as it answered them."""

    def __init__(self, status: int, code: str, message: str, reasons: list[dict[str, str]]) -> None:
        super().__init__(message, reasons=reasons)
        self.status = status
        self.code = code


class Remote:
    """A KyberCore server at ``url``, reached with ``token`` when it asks for one."""

    def __init__(self, url: str, token: str | None) -> None:
        import httpx  # here, not at import: the commands that edit files start faster

        self.url = url.rstrip("/")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        # Writes may be a large G-code upload over a slow link.
        timeout = httpx.Timeout(30.0, write=300.0)
        self._client: httpx.Client = httpx.Client(
            base_url=self.url, headers=headers, timeout=timeout
        )

    def __enter__(self) -> Remote:
        return self

    def __exit__(self, *_: object) -> None:
        self._client.close()

    def call(self, method: str, path: str, **request: Any) -> Any:
        """The JSON answer to a request (None for an empty one); :class:`RemoteError` for
        an error answer, :class:`KyberCoreError` when the server cannot be reached."""
        import httpx

        try:
            response = self._client.request(method, path, **request)
        except httpx.TransportError as exc:
            raise KyberCoreError(
                f"Cannot reach KyberCore at {self.url} ({exc or type(exc).__name__}). Start "
                "it with `kybercore serve`, or point --url (or $KYBERCORE_URL) at it."
            ) from None
        body = response.json() if response.content else None
        if response.is_success:
            return body
        error = body.get("error", {}) if isinstance(body, dict) else {}
        message = str(error.get("message") or f"HTTP {response.status_code}")
        fields = error.get("fields") or []
        if fields:
            message += "".join(f"\n  {f['field']}: {f['en']}" for f in fields)
        raise RemoteError(
            response.status_code,
            str(error.get("code", "error")),
            message,
            list(error.get("reasons") or []),
        )


@contextmanager
def remote_errors() -> Iterator[None]:
    """Turn errors into a red ``Error:`` line, the reasons below it, and an exit code."""
    try:
        yield
    except RemoteError as exc:
        exit_ = fail(exc.message, code=2 if exc.status == 422 else 1)
        print_reasons(exc.reasons)
        raise exit_ from None
    except KyberCoreError as exc:
        raise fail(exc.message) from None


def print_reasons(reasons: tuple[dict[str, str], ...] | list[dict[str, str]]) -> None:
    """The server's reasons, one ``- subject: text`` line each, on stderr."""
    for reason in reasons:
        subject = reason.get("subject")
        text = reason.get("en", "")
        err.print(Text(f"  - {subject}: {text}" if subject else f"  - {text}"))
