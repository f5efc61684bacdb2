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

Secret key files are written with mode 0600 (a new ``DIR`` 0700), existing key files are
never replaced without ``overwrite``, and a secret key is read only from a regular file that
neither group nor others can read (:func:`read_secret_key`; ``SecurityError`` naming the file
and the fix otherwise), as OpenSSH does for its private keys.
"""

from __future__ import annotations

import ipaddress
import os
import re
import stat
import threading
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import zmq

from hil_bridge.errors import SecurityError
from hil_bridge.files.config import read_text
from hil_bridge.outputs import atomic_output, check_output

__all__ = [
    "CurveKeys",
    "KeyAllowList",
    "check_bind",
    "generate_keys",
    "is_loopback_endpoint",
    "is_loopback_host",
    "read_public_key",
    "read_secret_key",
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
        public, secret = read_secret_key(secret_file)
        authorized = root / "authorized"
        keys = sorted(authorized.glob("*.key")) if authorized.is_dir() else []
        if not keys:
            raise ValueError(f"CURVE key directory {root}: no client keys in authorized/*.key")
        allowed = frozenset(read_public_key(k) for k in keys)
        return cls(public, secret, allowed)


_KEY_LINE = re.compile(r'^\s*(public|secret)-key\s*=\s*"([^"]*)"\s*$')
_Z85 = re.compile(r"^[0-9a-zA-Z.\-:+=^!/*?&<>()\[\]{}@%$#]{40}$")


def _load(path: Path) -> tuple[bytes, bytes | None]:
    """(public, secret or None) of a ``zmq.auth`` certificate file, checked strictly: UTF-8
    text, 40-character Z85 keys, and a secret key that yields its public key (so one flipped
    bit in either is caught, not used)."""
    keys: dict[str, bytes] = {}
    for line in read_text(path).splitlines():
        m = _KEY_LINE.match(line)
        if m is not None:
            if not _Z85.match(m.group(2)):
                raise ValueError(f"{path}: the {m.group(1)} key is not 40 Z85 characters")
            keys[m.group(1)] = m.group(2).encode()
    public, secret = keys.get("public"), keys.get("secret")
    if public is None:
        raise ValueError(f"{path}: not a CURVE key file (no public-key line)")
    if secret is not None and zmq.curve_public(secret) != public:
        raise ValueError(f"{path}: the secret key does not match the public key: a damaged "
                         "key file")
    return public, secret


def read_public_key(path: str | Path) -> bytes:
    """The z85 public key in a ``.key`` (or ``.key_secret``) file."""
    public, _ = _load(Path(path))
    if not public:
        raise ValueError(f"{path}: holds no public key")
    return public


def read_secret_key(path: str | Path) -> tuple[bytes, bytes]:
    """(public, secret) z85 keys from a ``.key_secret`` file that only its owner can read."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise ValueError(f"{p}: cannot read the secret key file ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{p}: the secret key is not a regular file")
    if st.st_mode & 0o077:
        raise SecurityError(
            f"{p}: secret key file is readable by group or others (mode "
            f"{stat.S_IMODE(st.st_mode):04o}); keys are read only from files of mode 0600 or "
            f"stricter: chmod 600 {p}"
        )
    public, secret = _load(p)
    if not secret:
        raise ValueError(f"{p}: holds no secret key (expected a .key_secret file)")
    return public, secret


def _write_key(path: Path, public: bytes, secret: bytes | None, *, overwrite: bool) -> None:
    """A certificate file in ``zmq.auth``'s format; a secret one gets mode 0600 before any
    key byte is written."""
    kind = "**Secret** Certificate" if secret else "Certificate"
    lines = [f"#   ZeroMQ CURVE {kind} (echoloop bus --keygen)", "", "metadata", "curve",
             f'    public-key = "{public.decode()}"']
    if secret:
        lines.insert(1, "#   DO NOT PROVIDE THIS FILE TO OTHER USERS nor change its permissions.")
        lines.append(f'    secret-key = "{secret.decode()}"')
    with atomic_output(path, overwrite=overwrite) as tmp:
        os.chmod(tmp, 0o600 if secret else 0o644)
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")


def generate_keys(directory: str | Path, clients: list[str], *, overwrite: bool = False) -> Path:
    """Write a server key pair and one key pair per client name, authorising every client.

    Secret files are 0600; existing key files are refused unless ``overwrite``."""
    root = Path(directory)
    for name in clients:
        if not name.isidentifier() or name == "server":
            raise ValueError(f"client name must be an identifier other than 'server', got {name!r}")
    names = ["server", *clients]
    planned = [root / f"{n}.key" for n in names] + [root / f"{n}.key_secret" for n in names]
    planned += [root / "authorized" / f"{n}.key" for n in clients]
    for path in planned:  # refuse before writing any key
        check_output(path, overwrite=overwrite)
    if not root.exists():
        root.mkdir(mode=0o700, parents=True)
    (root / "authorized").mkdir(exist_ok=True)
    for name in names:
        public, secret = zmq.curve_keypair()
        _write_key(root / f"{name}.key", public, None, overwrite=overwrite)
        _write_key(root / f"{name}.key_secret", public, secret, overwrite=overwrite)
        if name != "server":
            _write_key(root / "authorized" / f"{name}.key", public, None, overwrite=overwrite)
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
