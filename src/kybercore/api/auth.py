"""Who may do what: bearer tokens with roles, stored hashed next to printers.json.

Roles are ordered: ``viewer`` (read the fleet) < ``operator`` (print actions, G-code,
uploads) < ``admin`` (add, edit, remove printers). A token is shown once when created;
the file keeps only its SHA-256 (tokens are 256 random bits, so a slow hash adds nothing).

KyberCore runs open (everyone is admin) only when it listens on loopback and no token
exists; anywhere else it requires a token, or refuses to start and says why.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Final, Literal

import filelock

from kybercore.errors import ConfigError, InvalidInput

Role = Literal["viewer", "operator", "admin"]
ROLES: Final[tuple[Role, ...]] = ("viewer", "operator", "admin")
TOKEN_PREFIX: Final = "kc_"  # noqa: S105 -- a prefix that makes tokens recognisable
COOKIE: Final = "kybercore_token"


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


def hash_token(token: str) -> str:
    """The stored form of a token."""
    return hashlib.sha256(token.encode()).hexdigest()


class TokenStore:
    """tokens.json: create, list, revoke and check tokens (atomic, locked writes)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = filelock.FileLock(path.with_name(path.name + ".lock"), timeout=10)
        self._cache: tuple[float, list[TokenRecord]] | None = None

    def records(self) -> list[TokenRecord]:
        """Every stored token (re-read when the file changed)."""
        try:
            mtime = self.path.stat().st_mtime
        except FileNotFoundError:
            return []
        if self._cache is None or self._cache[0] != mtime:
            self._cache = (mtime, self._read())
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

    def identify(self, token: str) -> Identity | None:
        """The identity a presented token belongs to, or None."""
        digest = hash_token(token)
        for record in self.records():
            if hmac.compare_digest(record.sha256, digest):
                return Identity(record.name, record.role)
        return None

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
        self.path.parent.mkdir(parents=True, exist_ok=True)
        body = json.dumps({"version": 1, "tokens": [asdict(r) for r in records]}, indent=2)
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=".tokens-", suffix=".tmp")
        with os.fdopen(fd, "w") as handle:
            handle.write(body + "\n")
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o600)
        os.replace(tmp, self.path)
        self._cache = None


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
