"""Who may do what: bearer tokens with roles, stored hashed next to printers.json, and the
browser sessions made from them.

Roles are ordered: ``viewer`` (read the fleet) < ``operator`` (print actions, G-code,
uploads) < ``admin`` (add, edit, remove printers). A token is shown once when created;
the file keeps only its SHA-256 (tokens are 256 random bits, so a slow hash adds nothing).
The server re-reads tokens.json whenever it changes, so a token created or revoked with
the CLI counts at the next request.

A browser that logs in gets a session, not its token: a random id in an HttpOnly cookie,
kept in this process's memory (a restart logs browsers out), valid for
:data:`SESSION_SECONDS`, ended by logout or by revoking the token it was made from.

KyberCore runs open (everyone is admin) only when it listens on loopback and no token
exists; anywhere else it requires a token, or refuses to start and says why.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import secrets
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Final, Literal

import filelock

from kybercore.errors import ConfigError, InvalidInput
from kybercore.files import replace_file
from kybercore.registry.store import Signature, file_signature

Role = Literal["viewer", "operator", "admin"]
ROLES: Final[tuple[Role, ...]] = ("viewer", "operator", "admin")
TOKEN_PREFIX: Final = "kc_"  # noqa: S105 -- a prefix that makes tokens recognisable
COOKIE: Final = "kybercore_session"
SESSION_SECONDS: Final = 12 * 3600
"""How long a browser login lasts; then the page asks for the token again."""
SERVER_RECHECK_SECONDS: Final = 0.5
"""How stale the server's copy of tokens.json may be: a token created or revoked from
another shell counts within this. In exchange requests look at the file at most twice a
second, so identifying one needs no file access and can run on the event loop."""


@dataclass(frozen=True)
class Identity:
    """Who made a request."""

    name: str
    role: Role

    def may(self, needed: Role) -> bool:
        """Whether this identity's role is at least ``needed``."""
        return ROLES.index(self.role) >= ROLES.index(needed)


OPEN_ACCESS: Final = Identity("local", "admin")
"""Everyone, when KyberCore runs open on loopback."""


@dataclass(frozen=True)
class TokenRecord:
    """A token as stored: never the token itself."""

    id: str
    name: str
    role: Role
    sha256: str
    created: float

    def identity(self) -> Identity:
        """Who presents this token."""
        return Identity(self.name, self.role)


def hash_token(token: str) -> str:
    """The stored form of a token."""
    return hashlib.sha256(token.encode()).hexdigest()


class TokenStore:
    """tokens.json: create, list, revoke and check tokens (atomic, locked writes)."""

    def __init__(self, path: Path, *, recheck: float = 0.0) -> None:
        """``recheck``: seconds for which the last look at the file stands (the server's
        :data:`SERVER_RECHECK_SECONDS`; 0, for the CLI, looks every time)."""
        self.path = path
        self._lock = filelock.FileLock(path.with_name(path.name + ".lock"), timeout=10)
        self._cache: tuple[Signature, list[TokenRecord]] | None = None
        self._recheck = recheck
        self._checked = 0.0

    def records(self) -> list[TokenRecord]:
        """Every stored token (re-read when the file changed: one stat otherwise, none
        within ``recheck`` seconds of the last)."""
        now = time.monotonic()
        if self._cache is not None and now - self._checked < self._recheck:
            return list(self._cache[1])
        signature = file_signature(self.path)
        self._checked = now
        if signature is None:
            self._cache = (None, [])
        elif self._cache is None or self._cache[0] != signature:
            self._cache = (signature, self._read())
        return list(self._cache[1])

    def create(self, name: str, role: str) -> tuple[TokenRecord, str]:
        """Store a new token; returns its record and the token (shown once)."""
        if role not in ROLES:
            raise InvalidInput(f"Unknown role '{role}': use one of {', '.join(ROLES)}.")
        if not name.strip() or len(name) > 64:
            raise InvalidInput("A token needs a name of 1-64 characters (who or what uses it).")
        token = TOKEN_PREFIX + secrets.token_urlsafe(32)
        record = TokenRecord(
            id="t_" + secrets.token_hex(4),
            name=name.strip(),
            role=ROLES[ROLES.index(role)],  # the Role literal, checked above
            sha256=hash_token(token),
            created=time.time(),
        )
        with self._lock:
            self._write([*self._read(), record])
        return record, token

    def revoke(self, token_id: str) -> TokenRecord:
        """Delete a token by id."""
        with self._lock:
            records = self._read()
            kept = [r for r in records if r.id != token_id]
            if len(kept) == len(records):
                raise InvalidInput(f"No token with id '{token_id}'. See `kybercore tokens list`.")
            self._write(kept)
        return next(r for r in records if r.id == token_id)

    def find(self, token: str) -> TokenRecord | None:
        """The record of a presented token, or None."""
        digest = hash_token(token)
        for record in self.records():
            if hmac.compare_digest(record.sha256, digest):
                return record
        return None

    def get(self, token_id: str) -> TokenRecord | None:
        """The record with this id, or None once it is revoked."""
        return next((r for r in self.records() if r.id == token_id), None)

    def identify(self, token: str) -> Identity | None:
        """The identity a presented token belongs to, or None."""
        record = self.find(token)
        return record.identity() if record else None

    def _read(self) -> list[TokenRecord]:
        try:
            data = json.loads(self.path.read_text())
            return [TokenRecord(**item) for item in data["tokens"]]
        except FileNotFoundError:
            return []
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(
                f"{self.path} is not a valid token file ({exc}). Fix or delete it, then "
                "create tokens again with `kybercore tokens create`."
            ) from None

    def _write(self, records: list[TokenRecord]) -> None:
        body = json.dumps({"version": 1, "tokens": [asdict(r) for r in records]}, indent=2)
        replace_file(self.path, (body + "\n").encode())
        self._cache = None


@dataclass(frozen=True)
class _Session:
    token_id: str
    expires: float


class BrowserSessions:
    """Browser logins: session id -> the token it was made from, until it expires."""

    def __init__(
        self, lifetime: float = SESSION_SECONDS, clock: Callable[[], float] = time.time
    ) -> None:
        self.lifetime = lifetime
        self._clock = clock
        self._sessions: dict[str, _Session] = {}

    def create(self, token_id: str) -> str:
        """A new session for the token ``token_id``; returns its id (the cookie's value)."""
        now = self._clock()
        # Expired sessions go when a new one comes: memory follows the logins of a day.
        self._sessions = {k: s for k, s in self._sessions.items() if s.expires > now}
        session_id = secrets.token_urlsafe(32)
        self._sessions[session_id] = _Session(token_id, now + self.lifetime)
        return session_id

    def identify(self, session_id: str, store: TokenStore) -> Identity | None:
        """Who holds this session: None once it expired, ended or lost its token."""
        session = self._sessions.get(session_id)
        if session is None:
            return None
        record = store.get(session.token_id)
        if record is None or session.expires <= self._clock():
            self.end(session_id)
            return None
        return record.identity()

    def end(self, session_id: str) -> None:
        """Forget a session (logout)."""
        self._sessions.pop(session_id, None)


def tokens_path_for(printers_file: Path) -> Path:
    """Tokens live beside the fleet they guard."""
    return printers_file.with_name("tokens.json")


def access_mode(loopback: bool, store: TokenStore) -> Literal["open", "tokens"]:
    """``open`` on loopback with no tokens; ``tokens`` when tokens exist.

    Raises ConfigError when KyberCore would listen beyond loopback with no token to ask for.
    """
    if store.records():
        return "tokens"
    if loopback:
        return "open"
    raise ConfigError(
        "KyberCore controls printers: it will not listen beyond loopback without access "
        f"control. Create an admin token first (`kybercore tokens create NAME --role admin`, "
        f"stored in {store.path}), or listen on 127.0.0.1."
    )
