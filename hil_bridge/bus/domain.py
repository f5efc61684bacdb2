"""Domains, as ROS 2's ``ROS_DOMAIN_ID``: every fixed name a run binds or writes, from one number.

Two runs on one machine (two ``make demo``, two CI jobs on one runner) must not collide, so
nothing binds a fixed port or writes a fixed path: it asks the run's :class:`Domain`.
Domain ``N`` (0 <= N <= :data:`MAX_DOMAIN`) owns:

=============================  ==========================================================
bus (publish / subscribe)      ``tcp://127.0.0.1:{7400 + 10 N}`` / port ``7401 + 10 N``
live view (Foxglove)           ``ws://127.0.0.1:{8765 + 10 N}``
pty links, temporary files     ``{runtime}/{N}/`` (e.g. ``{runtime}/{N}/sonar0``)
files shared in memory         ``{shared}/d{N}/{tag}-{pid}-{random}/`` (:meth:`Domain.shared_dir`)
python-can virtual channels    ``{name}.d{N}`` (e.g. ``glider.d0``)
CAN across processes           python-can ``udp_multicast`` group ``239.255.74.{N}``, port
                               ``{7402 + 10 N}``, hop limit 0 (never leaves the host)
ArduPilot SITL (JSON physics)  SITL instance ``N`` (``-I N``): UDP ``{9002 + 10 N}``, and
                               SITL's own MAVLink TCP ``{5760 + 10 N}`` up (its SERIAL1
                               ``{5762 + 10 N}`` takes echoloop's range finders)
PX4 SITL (MAVLink HIL)         PX4 instance ``N`` (``px4 -i N``): the simulator's TCP
                               ``{4560 + N}``
=============================  ==========================================================

so domain 0 keeps the defaults of ``docs/spec/protocols.md`` (7400/7401) and Foxglove's 8765,
and the sets of two domains are disjoint (bus ports stay below 8765 for every domain).
``{runtime}`` is private to the user: ``$XDG_RUNTIME_DIR/echoloop`` when that directory is
usable, else ``{tempdir}/echoloop-{uid}``, created with mode 0700 and refused when another
user owns it; ``{shared}`` is ``/dev/shm/echoloop-{uid}`` (RAM) where there is one, else
``{runtime}/shm``, and a private domain's files go under its token there.

A *private* domain (:meth:`Domain.private`, used by the ``echoloop_launch`` pytest fixture) has
no number: an in-process ``mem://`` bus, channel names and a directory of its own, and an
ephemeral live-view port, so pytest-xdist workers and threads never share anything.

Which domain applies (highest first):

1. an explicit choice: ``--domain N`` on a command, ``run(..., domain=N)``, ``Domain(N)``;
2. the domain a launch runner activated while it constructs its nodes (:func:`use`), which is
   how a node's defaults (``SonarHeadAdapter`` port, ``MockSonarHead`` link, virtual CAN
   channel, ``LiveView`` port) follow ``--domain`` without a parameter of their own;
3. the environment variable ``ECHOLOOP_DOMAIN`` (set it once per shell or CI job; every
   command and tool follows it);
4. domain 0.

Names given explicitly (a ``bus:`` URL, a ``port``/``link`` path, a CAN ``channel``) are used
as given: a domain only fills in what is left out.

A launch run holds a shared lock on its numbered domain (:meth:`Domain.claim`, a ``flock`` on
``{runtime}/{N}/.run.lock``) from before its nodes exist until they stopped. A domain is *busy*
when a run holds it, one of its bus ports is bound, or its directory has a live pty link.
:func:`claim_first_free` (``--domain auto``) finds and claims a free one under a lock of its
own, so two runs started at once never pick the same domain.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import secrets
import socket
import stat
import tempfile
from collections.abc import Iterator
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "BUS_PORT_BASE",
    "DOMAIN_ENV",
    "DOMAIN_STRIDE",
    "LIVE_PORT_BASE",
    "MAX_DOMAIN",
    "Domain",
    "claim_first_free",
    "current",
    "first_free",
    "parse_domain",
    "resolve",
    "runtime_root",
    "shared_root",
    "use",
]

#: the environment variable naming the domain of every command in this shell / CI job
DOMAIN_ENV = "ECHOLOOP_DOMAIN"
#: highest domain number (ports stay below 65536 and bus ports below the live-view base)
MAX_DOMAIN = 99
#: publish port of domain 0 (its subscribe port is one above)
BUS_PORT_BASE = 7400
#: live-view port of domain 0 (Foxglove's default)
LIVE_PORT_BASE = 8765
#: ports between two consecutive domains
DOMAIN_STRIDE = 10

_ACTIVE: ContextVar[Domain | None] = ContextVar("echoloop_domain", default=None)


def runtime_root() -> Path:
    """This user's private directory for pty links and temporary files (created, mode 0700).

    ``$XDG_RUNTIME_DIR/echoloop`` if ``XDG_RUNTIME_DIR`` names a directory this user may write,
    else ``{tempfile.gettempdir()}/echoloop-{uid}``. Raises ``PermissionError`` when the
    directory exists but belongs to another user or is a symlink (someone may be squatting it).
    """
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    if xdg and os.path.isdir(xdg) and os.access(xdg, os.W_OK | os.X_OK):
        root = Path(xdg) / "echoloop"
    else:
        uid = os.getuid() if hasattr(os, "getuid") else 0
        root = Path(tempfile.gettempdir()) / f"echoloop-{uid}"
    _private_dir(root)
    return root


def shared_root() -> Path:
    """This user's directory for files the processes of a run share in memory (created, mode
    0700, checked as :func:`runtime_root`): ``/dev/shm/echoloop-{uid}`` where ``/dev/shm`` is a
    writable directory (a RAM file system on Linux), else ``{runtime_root()}/shm``."""
    shm = Path("/dev/shm")
    if shm.is_dir() and os.access(shm, os.W_OK | os.X_OK):
        uid = os.getuid() if hasattr(os, "getuid") else 0
        return _private_dir(shm / f"echoloop-{uid}")
    return _private_dir(runtime_root() / "shm")


def _private_dir(path: Path) -> Path:
    """Create ``path`` (mode 0700) or check that the existing one is ours and private."""
    with contextlib.suppress(FileExistsError):
        path.mkdir(mode=0o700, parents=False)
    st = os.lstat(path)
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        raise PermissionError(f"{path}: expected a directory, found something else; remove it")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise PermissionError(f"{path}: belongs to uid {st.st_uid}, not to you; remove it")
    if st.st_mode & 0o077:
        path.chmod(0o700)
    return path


def _port_free(port: int) -> bool:
    """True if 127.0.0.1:``port`` can be bound now (probed as ZeroMQ binds: SO_REUSEADDR)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError as exc:
            if exc.errno in (errno.EADDRINUSE, errno.EACCES):
                return False
            raise
    return True


@dataclass(frozen=True, slots=True)
class Domain:
    """The fixed names of one domain (see the module docstring).

    ``Domain(3)`` is numbered domain 3; :meth:`private` makes an unnumbered one
    (``number is None``) with its own ``token`` and directory.
    """

    number: int | None
    token: str = ""
    directory: Path | None = None

    def __post_init__(self) -> None:
        if self.number is None:
            if not self.token or self.directory is None:
                raise ValueError("a private domain needs a token and a directory "
                                 "(use Domain.private())")
            return
        if isinstance(self.number, bool) or not isinstance(self.number, int) or not (
            0 <= self.number <= MAX_DOMAIN
        ):
            raise ValueError(f"domain: expected an integer 0..{MAX_DOMAIN}, got {self.number!r}")
        object.__setattr__(self, "token", self.token or f"d{self.number}")

    @classmethod
    def private(cls, directory: str | os.PathLike[str]) -> Domain:
        """A domain shared with nothing: ``mem://`` bus, own channel names, and ``directory``
        (created if missing; e.g. pytest's ``tmp_path``) for its pty links."""
        where = Path(directory)
        where.mkdir(mode=0o700, parents=True, exist_ok=True)
        return cls(None, f"p{os.getpid():x}x{secrets.token_hex(4)}", where)

    @property
    def bus_url(self) -> str:
        """Default bus URL (publish endpoint; the subscribe endpoint is port + 1)."""
        if self.number is None:
            return f"mem://echoloop-{self.token}"
        return f"tcp://127.0.0.1:{BUS_PORT_BASE + DOMAIN_STRIDE * self.number}"

    @property
    def live_port(self) -> int:
        """Default live-view (Foxglove WebSocket) port; 0 (ephemeral) for a private domain."""
        return 0 if self.number is None else LIVE_PORT_BASE + DOMAIN_STRIDE * self.number

    @property
    def sitl_instance(self) -> int | None:
        """The ArduPilot SITL instance (``-I``) this domain's SITL node serves by default: the
        domain number (None for a private domain: an ephemeral port)."""
        return self.number

    @property
    def px4_sitl_port(self) -> int | None:
        """The TCP port PX4 SITL instance N (``px4 -i N``) connects to its simulator on, which
        this domain's PX4 HIL node listens on: 4560 + N (None for a private domain: an
        ephemeral port)."""
        return None if self.number is None else 4560 + self.number

    @property
    def ardupilot_serial1_port(self) -> int | None:
        """ArduPilot SITL instance N's SERIAL1 (TCP 5762 + 10 N, MAVLink 2), where this
        domain's MAVLink range finder connects (None for a private domain)."""
        return None if self.number is None else 5762 + DOMAIN_STRIDE * self.number

    @property
    def ports(self) -> tuple[int, ...]:
        """The TCP ports this domain's defaults bind (bus publish, bus subscribe)."""
        if self.number is None:
            return ()
        base = BUS_PORT_BASE + DOMAIN_STRIDE * self.number
        return (base, base + 1)

    def dir(self) -> Path:
        """The domain's private directory (created, mode 0700)."""
        if self.directory is not None:
            return self.directory
        return _private_dir(runtime_root() / str(self.number))

    def path(self, name: str) -> Path:
        """A fixed file name inside the domain's directory, e.g. ``path("sonar0")``."""
        if not name or "/" in name or name in (".", ".."):
            raise ValueError(f"name: expected a plain file name, got {name!r}")
        return self.dir() / name

    def shared_dir(self, tag: str) -> Path:
        """A fresh directory for files this process shares in memory with its children (e.g.
        the echo workers' forest tiles): ``{shared_root()}/{token}/{tag}-{pid}-{random}``,
        mode 0700. The caller removes it (``hil_bridge.server.shared_tiles``)."""
        if not tag or "/" in tag or "-" in tag:
            raise ValueError(f"tag: expected a plain name without '-', got {tag!r}")
        name = f"{tag}-{os.getpid()}-{secrets.token_hex(4)}"
        try:
            where = _private_dir(shared_root() / self.token) / name
            where.mkdir(mode=0o700)
        except FileNotFoundError:  # another run just removed the emptied domain directory
            where = _private_dir(shared_root() / self.token) / name
            where.mkdir(mode=0o700)
        return where

    def can_channel(self, name: str = "glider") -> str:
        """The python-can ``virtual`` channel called ``name`` in this domain."""
        return f"{name}.{self.token}"

    def can_multicast(self) -> tuple[str, int]:
        """The python-can ``udp_multicast`` group and port of this domain's CAN bus across
        processes (a private domain has none: its nodes share one process)."""
        if self.number is None:
            raise ValueError(f"{self} has no CAN multicast group: its nodes share one process; "
                             "use interface 'virtual'")
        return f"239.255.74.{self.number}", BUS_PORT_BASE + DOMAIN_STRIDE * self.number + 2

    @contextlib.contextmanager
    def claim(self) -> Iterator[Domain]:
        """Hold this domain for a run: a shared lock other runs in it share, which makes it
        busy for :func:`claim_first_free` (a private domain needs none)."""
        if self.number is None:
            yield self
            return
        with open(self.dir() / ".run.lock", "a+b") as fd:
            fcntl.flock(fd.fileno(), fcntl.LOCK_SH)
            yield self

    def _run_holds_it(self) -> bool:
        lock = self.dir() / ".run.lock"
        if self.number is None or not lock.exists():
            return False
        with open(lock, "a+b") as fd:
            try:
                fcntl.flock(fd.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
        return False

    def busy_reason(self) -> str | None:
        """Why another run seems to hold this domain (a run's claim, a bus port in use, a live
        pty link in its directory), or None."""
        if self._run_holds_it():
            return "an echoloop run holds it"
        for port in self.ports:
            if not _port_free(port):
                return f"tcp://127.0.0.1:{port} is in use"
        root = self.directory or runtime_root() / str(self.number)
        if root.is_dir():
            for entry in sorted(root.iterdir()):
                if entry.is_symlink() and link_in_use(entry):
                    return f"{entry} links to a live pty ({os.readlink(entry)})"
        return None

    def __str__(self) -> str:
        return f"private domain {self.token}" if self.number is None else f"domain {self.number}"


def _owner_lock(link: Path) -> Path:
    return link.with_name(f".{link.name}.owner")


def hold_link(link: str | os.PathLike[str]) -> int:
    """Take ownership of the device link ``link`` for this process: an exclusive lock on a file
    beside it, held on the returned fd until it is closed (or the process ends, even by
    SIGKILL). ``ValueError`` if a live process owns it. A link's target alone cannot say this:
    pty numbers are reused, so a link left by a killed run may point at another program's pty."""
    path = Path(link)
    fd = os.open(_owner_lock(path), os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        target = os.readlink(path) if path.is_symlink() else "?"
        raise ValueError(f"link {str(path)!r} points to a pty another process holds open "
                         f"({target}); stop it, or use another link or domain") from None
    return fd


def link_in_use(link: str | os.PathLike[str]) -> bool:
    """True while a live process owns ``link`` (:func:`hold_link`)."""
    try:
        fd = os.open(_owner_lock(Path(link)), os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


def parse_domain(text: str | int, *, where: str = "domain") -> int:
    """``"3"`` -> 3; anything but an integer 0..MAX_DOMAIN raises ``ValueError`` naming it."""
    try:
        number = int(str(text).strip(), 10)
    except ValueError:
        raise ValueError(f"{where}={text!r}: expected an integer 0..{MAX_DOMAIN}") from None
    if not 0 <= number <= MAX_DOMAIN:
        raise ValueError(f"{where}={text!r}: expected an integer 0..{MAX_DOMAIN}")
    return number


def _from_env() -> Domain:
    text = os.environ.get(DOMAIN_ENV, "").strip()
    return Domain(parse_domain(text, where=DOMAIN_ENV) if text else 0)


def current() -> Domain:
    """The domain in effect here: the active one (:func:`use`), else ``ECHOLOOP_DOMAIN``, else 0."""
    active = _ACTIVE.get()
    return active if active is not None else _from_env()


def first_free(start: Domain | None = None) -> tuple[Domain, list[tuple[Domain, str]]]:
    """The first numbered domain from ``start`` (default: :func:`current`) that no other run
    seems to hold, and the busy ones skipped with why. ``ValueError`` if all are busy."""
    first = start if start is not None else current()
    if first.number is None:
        return first, []
    skipped: list[tuple[Domain, str]] = []
    for number in range(first.number, MAX_DOMAIN + 1):
        dom = Domain(number)
        reason = dom.busy_reason()
        if reason is None:
            return dom, skipped
        skipped.append((dom, reason))
    raise ValueError(f"every domain from {first.number} to {MAX_DOMAIN} is busy")


@contextlib.contextmanager
def claim_first_free(
    start: Domain | None = None,
) -> Iterator[tuple[Domain, list[tuple[Domain, str]]]]:
    """:func:`first_free`, claimed (:meth:`Domain.claim`) for the block; the search runs under
    a lock of this user's, so concurrent callers get different domains."""
    with open(runtime_root() / ".select.lock", "a+b") as select:
        fcntl.flock(select.fileno(), fcntl.LOCK_EX)
        found, skipped = first_free(start)
        with found.claim():
            fcntl.flock(select.fileno(), fcntl.LOCK_UN)
            yield found, skipped


def resolve(choice: Domain | int | str | None = None) -> Domain:
    """The domain for an explicit ``choice`` (a Domain, a number, ``"N"``), else :func:`current`.

    ``"auto"`` is :func:`first_free` from the current domain, unclaimed (a command that runs
    in it uses :func:`claim_first_free` instead).
    """
    if choice is None:
        return current()
    if isinstance(choice, Domain):
        return choice
    if isinstance(choice, str) and choice.strip() == "auto":
        return first_free()[0]
    return Domain(parse_domain(choice))


@contextlib.contextmanager
def use(domain: Domain) -> Iterator[Domain]:
    """Make ``domain`` the :func:`current` one in this thread (context) inside the block."""
    token = _ACTIVE.set(domain)
    try:
        yield domain
    finally:
        _ACTIVE.reset(token)
