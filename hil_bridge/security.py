"""Bus security: loopback by default, CURVE (with an allow-list of client keys) off loopback.

Policy (:func:`check_bind`): a proxy may bind a non-loopback address only with CURVE keys;
otherwise it refuses to start with :class:`~hil_bridge.errors.SecurityError`. With keys, every
client must present a public key from the allow-list; others are rejected during the ZeroMQ
handshake and counted by :class:`KeyAllowList` (the ZAP handler's callback).

Key directory layout (``echoloop bus --keygen DIR`` writes it; ``--curve-keys DIR`` reads it)::

    DIR/server.key            proxy public key   (give it to clients: ?curve_server=...)
    DIR/server.key_secret     proxy secret key   (stays on the proxy host)
    DIR/authorized/*.key      allowed client public keys
    DIR/<client>.key_secret   a client's key pair (?curve_client=...), one per client
"""

from __future__ import annotations

import ipaddress
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import zmq.auth

from hil_bridge.errors import SecurityError

__all__ = [
    "CurveKeys",
    "KeyAllowList",
    "check_bind",
    "generate_keys",
    "is_loopback_endpoint",
    "is_loopback_host",
]


def is_loopback_endpoint(endpoint: str) -> bool:
    """True for ``ipc://``/``inproc://`` and ``tcp://`` on a loopback address or ``localhost``.

    Wildcards (``*``, ``0.0.0.0``) and other host names count as non-loopback.
    """
    parts = urlsplit(endpoint)
    if parts.scheme in ("ipc", "inproc"):
        return True
    if parts.scheme != "tcp":
        raise ValueError(f"expected a tcp://, ipc:// or inproc:// endpoint, got {endpoint!r}")
    return is_loopback_host(parts.netloc.rpartition(":")[0].strip("[]"))


def is_loopback_host(host: str) -> bool:
    """True for ``localhost`` and loopback IP addresses; other names and wildcards are not."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_bind(endpoints: list[str], curve: CurveKeys | None) -> None:
    """Raise ``SecurityError`` if any endpoint is off loopback while ``curve`` is None."""
    exposed = [e for e in endpoints if not is_loopback_endpoint(e)]
    if exposed and curve is None:
        raise SecurityError(
            f"refusing to bind {exposed} without CURVE keys: binding off loopback exposes the "
            "bus; pass curve keys (echoloop bus --curve-keys DIR, keys from --keygen DIR)"
        )


@dataclass(frozen=True, slots=True)
class CurveKeys:
    """The proxy's CURVE key pair and the z85 public keys of the clients it allows."""

    server_public: bytes
    server_secret: bytes
    allowed: frozenset[bytes]

    @classmethod
    def from_dir(cls, directory: str | Path) -> CurveKeys:
        """Load the layout of the module docstring (``ValueError`` naming a missing file)."""
        root = Path(directory)
        secret_file = root / "server.key_secret"
        if not secret_file.is_file():
            raise ValueError(f"CURVE key directory {root}: missing {secret_file.name}")
        public, secret = zmq.auth.load_certificate(secret_file)
        if secret is None:
            raise ValueError(f"{secret_file} holds no secret key")
        authorized = root / "authorized"
        keys = sorted(authorized.glob("*.key")) if authorized.is_dir() else []
        if not keys:
            raise ValueError(f"CURVE key directory {root}: no client keys in authorized/*.key")
        allowed = frozenset(zmq.auth.load_certificate(k)[0] for k in keys)
        return cls(public, secret, allowed)


def generate_keys(directory: str | Path, clients: list[str]) -> Path:
    """Write a server key pair and one key pair per client name, authorising every client."""
    root = Path(directory)
    (root / "authorized").mkdir(parents=True, exist_ok=True)
    zmq.auth.create_certificates(root, "server")
    for name in clients:
        if not name.isidentifier() or name == "server":
            raise ValueError(f"client name must be an identifier other than 'server', got {name!r}")
        public_file, _ = zmq.auth.create_certificates(root, name)
        shutil.copy(public_file, root / "authorized" / Path(public_file).name)
    return root


class KeyAllowList:
    """ZAP credentials provider: allow listed z85 keys; count accepted and rejected handshakes."""

    def __init__(self, allowed: frozenset[bytes]) -> None:
        self._allowed = allowed
        self._lock = threading.Lock()
        self.accepted = 0
        self.rejected = 0
        self.rejected_keys: set[bytes] = set()

    def callback(self, domain: str, key: bytes) -> bool:
        ok = key in self._allowed
        with self._lock:
            if ok:
                self.accepted += 1
            else:
                self.rejected += 1
                self.rejected_keys.add(key)
        return ok

    def stats(self) -> dict[str, int]:
        with self._lock:
            return {"auth_accepted": self.accepted, "auth_rejected": self.rejected}
