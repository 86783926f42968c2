"""API keys, roles and one-shot tokens of the web gateway.

- Keys: ``nurbsmotion web keys add NAME --role operator|observer`` prints a random key once;
  only its SHA-256 is kept, in ``DATA_DIR/web/keys.json`` (mode 0600). A key is 32 random
  bytes, so a plain hash is as strong as a slow one would be (as API tokens are stored).
- Roles: an observer reads (GET, the WebSocket's status); an operator also moves the machine;
  ``abort`` is allowed to every authenticated client (stopping must never need more rights).
- One-shot tokens (``POST /api/v1/access/oneshot``, as Moonraker's): valid once, for 5 s, with
  the role of the key that asked; for a WebSocket opened by a page that cannot set headers.
- Failed attempts are counted per client address: more than ``MAX_FAILURES`` within
  ``FAILURE_WINDOW_S`` and that address is refused (429) until the window passes.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import json
import os
import re
import secrets
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from nurbsmotion.errors import InputError

KEY_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
ONESHOT_S = 5.0
MAX_FAILURES = 10
FAILURE_WINDOW_S = 60.0


class Role(str, enum.Enum):
    OBSERVER = "observer"
    OPERATOR = "operator"

    def allows(self, needed: "Role") -> bool:
        return self is Role.OPERATOR or needed is Role.OBSERVER


@dataclass(frozen=True)
class ApiKey:
    name: str
    role: Role
    sha256: str
    created: float


def key_hash(key: str) -> str:
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


class KeyStore:
    """The gateway's keys in ``DATA_DIR/web/keys.json``; read again when the file changes."""

    def __init__(self, data_dir: str | Path) -> None:
        self.path = Path(data_dir) / "web" / "keys.json"
        self._stamp: tuple[int, int] | None = None
        self._keys: dict[str, ApiKey] = {}

    def keys(self) -> list[ApiKey]:
        self._reload()
        return sorted(self._keys.values(), key=lambda k: k.name)

    def add(self, name: str, role: Role) -> str:
        """A new key for ``name`` (printed once, never stored in the clear)."""
        if not KEY_NAME.match(name):
            raise InputError("name", f"{name!r}: 1-64 letters, digits, '.', '_' or '-', starting with a letter or digit")
        self._reload()
        if name in self._keys:
            raise InputError("name", f"a key named {name!r} exists (remove it first)")
        key = secrets.token_urlsafe(32)
        self._keys[name] = ApiKey(name, role, key_hash(key), time.time())
        self._save()
        return key

    def remove(self, name: str) -> None:
        self._reload()
        if self._keys.pop(name, None) is None:
            raise InputError("name", f"no key named {name!r}")
        self._save()

    def role_of(self, key: str) -> ApiKey | None:
        """The key's record, compared in constant time against every stored hash."""
        self._reload()
        digest = key_hash(key)
        found = None
        for record in self._keys.values():
            if hmac.compare_digest(record.sha256, digest):
                found = record
        return found

    def _reload(self) -> None:
        try:
            st = self.path.stat()
        except FileNotFoundError:
            self._keys, self._stamp = {}, None
            return
        stamp = (st.st_mtime_ns, st.st_size)
        if stamp == self._stamp:
            return
        try:
            raw = json.loads(self.path.read_text())
            self._keys = {k["name"]: ApiKey(k["name"], Role(k["role"]), k["sha256"], float(k["created"]))
                          for k in raw["keys"]}
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise InputError(str(self.path), f"unreadable key file: {err}") from None
        self._stamp = stamp

    def _save(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        tmp = self.path.with_suffix(".tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            json.dump({"keys": [{"name": k.name, "role": k.role.value, "sha256": k.sha256, "created": k.created}
                                for k in self._keys.values()]}, f, indent=1)
        os.replace(tmp, self.path)
        os.chmod(self.path, 0o600)
        self._stamp = None


class OneShotTokens:
    """Tokens valid once, for ONESHOT_S seconds, each with the role it was made for."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._tokens: dict[str, tuple[Role, float]] = {}

    def issue(self, role: Role) -> str:
        self._expire()
        token = secrets.token_urlsafe(24)
        self._tokens[token] = (role, self._clock() + ONESHOT_S)
        return token

    def redeem(self, token: str) -> Role | None:
        self._expire()
        entry = self._tokens.pop(token, None)
        return entry[0] if entry is not None else None

    def _expire(self) -> None:
        now = self._clock()
        for token in [t for t, (_, until) in self._tokens.items() if until < now]:
            del self._tokens[token]


class FailedAttempts:
    """Failed authentications per client address within a sliding window."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._failures: dict[str, list[float]] = {}

    def blocked(self, address: str) -> bool:
        return len(self._recent(address)) >= MAX_FAILURES

    def add(self, address: str) -> int:
        recent = self._recent(address)
        recent.append(self._clock())
        self._failures[address] = recent
        return len(recent)

    def _recent(self, address: str) -> list[float]:
        since = self._clock() - FAILURE_WINDOW_S
        return [t for t in self._failures.get(address, []) if t >= since]
