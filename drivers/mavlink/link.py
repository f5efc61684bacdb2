"""MAVLink links from a URL: one peer over TCP (either end), UDP or a serial port.

``open_mavlink(url, ...)`` picks the backend by the URL's scheme from :data:`SCHEMES`
(``"module:Class"``, imported when used), as ``open_transport`` does for the bus:

======================================  ================================================
``tcpin://HOST:PORT``                   listen; serve the one peer that connects (PX4 SITL
                                        connects to its simulator on 4560 + instance); a new
                                        peer replaces the old one (a restarted PX4)
``tcp://HOST:PORT``                     connect, and connect again after a drop (ArduPilot
                                        SITL's SERIAL1/SERIAL2 ports, a MAVProxy output)
``udpin://HOST:PORT``                   bind; answer whoever sent last
``udp://HOST:PORT``                     send to HOST:PORT from an ephemeral port
``serial:///dev/ttyACM0?baud=921600``   a serial port (pyserial; a bare path works too):
                                        a flight controller's USB (HITL), a telemetry radio
======================================  ================================================

:class:`MavlinkLink` contract:

1. Constructing a link binds what it listens on (``tcpin``, ``udpin``), so a port in use
   fails at start naming it; a peer is connected lazily, by :meth:`~MavlinkLink.recv`.
2. :meth:`~MavlinkLink.send` packs a pymavlink message with the link's own system and
   component ids and a rising sequence number, and writes it whole, from any thread
   (:meth:`~MavlinkLink.send_many`: several in one write); with no peer connected it writes
   nothing and returns False (``send_dropped``).
3. :meth:`~MavlinkLink.recv` (one reader thread) waits up to ``timeout_s`` for bytes and
   returns the messages they complete. A frame that fails its checksum, or is not MAVLink, is
   dropped and counted (``bad``); a message the dialect does not know is dropped and counted
   (``unknown``). A peer that goes away is counted (``disconnects``) and looked for again
   (``connects`` counts every peer found); the link never ends by itself.
4. :meth:`~MavlinkLink.close` is idempotent; ``stats()`` has the counters and the bytes in
   and out.

Messages are MAVLink 2 (``pymavlink.dialects.v20.common``): PX4 and ArduPilot read both
versions, and only MAVLink 2 carries the extension fields (``HIL_SENSOR.id``,
``DISTANCE_SENSOR.signal_quality``).
"""

from __future__ import annotations

import importlib
import logging
import select
import socket
import threading
import time
import urllib.parse
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["SCHEMES", "MavlinkLink", "mavlink", "open_mavlink"]

log = logging.getLogger(__name__)

#: scheme -> "module:Class" of its backend
SCHEMES = {
    "tcpin": "drivers.mavlink.link:TcpServerLink",
    "tcp": "drivers.mavlink.link:TcpClientLink",
    "udpin": "drivers.mavlink.link:UdpLink",
    "udp": "drivers.mavlink.link:UdpLink",
    "serial": "drivers.mavlink.link:SerialLink",
}
_RECONNECT_S = 0.5
_COUNTERS = ("messages_in", "bad", "unknown", "sent", "send_dropped", "bytes_in", "bytes_out",
             "connects", "disconnects")


def _host_port(url: str, parts: urllib.parse.SplitResult) -> tuple[str, int]:
    try:
        port = parts.port
    except ValueError:
        port = None
    if port is None or parts.hostname is None:
        raise ValueError(f"MAVLink link {url!r}: expected {parts.scheme}://HOST:PORT")
    return parts.hostname, port


def open_mavlink(url: str, *, system: int = 1, component: int = 158) -> MavlinkLink:
    """The link for ``url`` (module docstring); ``system``, ``component``: the ids it sends
    with (158: MAV_COMP_ID_PERIPHERAL)."""
    if url.startswith("/"):
        url = "serial://" + url
    scheme = url.split("://", 1)[0] if "://" in url else ""
    target = SCHEMES.get(scheme)
    if target is None:
        raise ValueError(f"MAVLink link {url!r}: unknown scheme {scheme!r}; expected one of "
                         f"{sorted(SCHEMES)} (or a device path)")
    if not (1 <= system <= 255 and 0 <= component <= 255):
        raise ValueError(f"MAVLink ids: expected system 1..255 and component 0..255, got "
                         f"{system}, {component}")
    module, cls = target.split(":")
    backend: type[MavlinkLink] = getattr(importlib.import_module(module), cls)
    return backend(url, system=system, component=component)


class MavlinkLink(ABC):
    """One MAVLink peer (module docstring). Backends implement ``_connect``, ``_read``,
    ``_write`` and ``_close``."""

    def __init__(self, url: str, *, system: int, component: int) -> None:
        self.url = url
        self._encoder = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
        self._decoder = mavlink.MAVLink(None)
        self._decoder.robust_parsing = True
        self._send_lock = threading.Lock()
        self._closed = False
        self._c = dict.fromkeys(_COUNTERS, 0)
        self._next_try = 0.0

    @property
    @abstractmethod
    def connected(self) -> bool:
        """Whether a peer is there to write to."""

    @abstractmethod
    def _connect(self, timeout_s: float) -> bool:
        """Look for a peer for up to ``timeout_s``; True when one is connected (counted by
        :meth:`_found`, under the send lock, as the peer is taken)."""

    def _found(self) -> None:
        """A new peer is taken (call under the send lock): the next generation."""
        self._c["connects"] += 1

    @abstractmethod
    def _read(self, timeout_s: float) -> bytes | None:
        """Bytes from the peer within ``timeout_s`` (b"": none yet); None: the peer is gone."""

    @abstractmethod
    def _write(self, data: bytes) -> bool:
        """Write ``data`` whole to the peer (called under the send lock); False if gone."""

    @abstractmethod
    def _close(self) -> None:
        """Release every socket or port (idempotent)."""

    def send(self, msg: Any) -> bool:
        """Pack and write ``msg`` (contract 2); True if it was written."""
        return self.send_many((msg,))

    @property
    def generation(self) -> int:
        """How many peers this link has found: a peer's messages are written only to it when
        sent with its ``generation`` (:meth:`send_many`)."""
        return self._c["connects"]

    def send_many(self, msgs: Sequence[Any], generation: int | None = None) -> bool:
        """Pack ``msgs`` and write them in one go (one system call on a socket), in order;
        True if they were written. With ``generation``, only while that peer is connected
        (a message meant for a peer that has gone is never written to the next one)."""
        with self._send_lock:
            if self._closed or not self.connected or (
                    generation is not None and generation != self._c["connects"]):
                self._c["send_dropped"] += len(msgs)
                return False
            data = b"".join([m.pack(self._encoder) for m in msgs])
            if not self._write(data):
                self._c["send_dropped"] += len(msgs)
                return False
            self._c["sent"] += len(msgs)
            self._c["bytes_out"] += len(data)
            return True

    def recv(self, timeout_s: float = 0.1) -> list[Any]:
        """The messages completed within ``timeout_s`` (contract 3)."""
        if self._closed:
            return []
        if not self.connected:
            now = time.monotonic()
            if now < self._next_try:
                time.sleep(min(timeout_s, self._next_try - now))
                return []
            if not self._connect(timeout_s):
                self._next_try = time.monotonic() + self._retry_s()
                return []
            self._decoder = mavlink.MAVLink(None)
            self._decoder.robust_parsing = True
        data = self._read(timeout_s)
        if data is None:
            self._gone()
            return []
        return self._parse(data)

    def _retry_s(self) -> float:
        """How long to wait before looking for a peer again after a failed look."""
        return 0.0

    def _gone(self) -> None:
        self._c["disconnects"] += 1
        log.info("MAVLink link %s: peer gone", self.url)
        with self._send_lock:
            self._drop_peer()

    @abstractmethod
    def _drop_peer(self) -> None:
        """Forget the connected peer (under the send lock)."""

    def _parse(self, data: bytes) -> list[Any]:
        if not data:
            return []
        self._c["bytes_in"] += len(data)
        out = []
        for msg in self._decoder.parse_buffer(data) or ():
            kind = msg.get_type()
            if kind == "BAD_DATA":
                self._c["bad"] += 1
            elif kind.startswith("UNKNOWN_"):
                self._c["unknown"] += 1
            else:
                out.append(msg)
        self._c["messages_in"] += len(out)
        return out

    def stats(self) -> dict[str, Any]:
        return {"url": self.url, "connected": self.connected, **self._c}

    def close(self) -> None:
        with self._send_lock:
            if self._closed:
                return
            self._closed = True
            self._close()

    def __enter__(self) -> MavlinkLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _SocketPeer(MavlinkLink):
    """A link whose peer is one connected stream socket."""

    def __init__(self, url: str, *, system: int, component: int) -> None:
        super().__init__(url, system=system, component=component)
        self._peer: socket.socket | None = None

    @property
    def connected(self) -> bool:
        return self._peer is not None

    def _read(self, timeout_s: float) -> bytes | None:
        peer = self._peer
        if peer is None:
            return None
        try:
            ready, _, _ = select.select([peer], [], [], timeout_s)
            if not ready:
                return b""
            data = peer.recv(65536)
        except (OSError, ValueError):
            return None
        return data if data else None

    def _write(self, data: bytes) -> bool:
        peer = self._peer
        if peer is None:
            return False
        try:
            peer.sendall(data)
        except OSError:
            return False
        return True

    def _drop_peer(self) -> None:
        if self._peer is not None:
            self._peer.close()
            self._peer = None

    def _adopt(self, sock: socket.socket) -> None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self._send_lock:
            self._drop_peer()
            self._peer = sock
            self._found()


class TcpServerLink(_SocketPeer):
    """``tcpin://HOST:PORT``: listens (bound at construction), serves the latest peer."""

    def __init__(self, url: str, *, system: int, component: int) -> None:
        super().__init__(url, system=system, component=component)
        host, port = _host_port(url, urllib.parse.urlsplit(url))
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((host, port))
        except OSError as exc:
            self._listener.close()
            raise OSError(exc.errno, f"MAVLink link {url}: cannot listen on TCP {host}:{port} "
                          f"({exc.strerror})") from exc
        self._listener.listen(1)
        #: the port listened on (the one given, or the one the OS chose for port 0)
        self.port = int(self._listener.getsockname()[1])

    def _connect(self, timeout_s: float) -> bool:
        try:
            ready, _, _ = select.select([self._listener], [], [], timeout_s)
            if not ready:
                return False
            sock, addr = self._listener.accept()
        except (OSError, ValueError):
            return False
        log.info("MAVLink link %s: peer %s:%s connected", self.url, *addr[:2])
        self._adopt(sock)
        return True

    def _read(self, timeout_s: float) -> bytes | None:
        """Bytes from the peer; a new peer knocking replaces it (the old one is gone)."""
        peer = self._peer
        if peer is None:
            return None
        try:
            ready, _, _ = select.select([peer, self._listener], [], [], timeout_s)
        except (OSError, ValueError):
            return None
        if peer in ready:  # what the old peer sent before a new one knocked comes first
            return super()._read(0.0)
        if self._listener in ready:
            return None  # a restarted peer: the next recv() accepts it
        return b""

    def _close(self) -> None:
        self._drop_peer()
        self._listener.close()


class TcpClientLink(_SocketPeer):
    """``tcp://HOST:PORT``: connects, and again after a drop (every ``_RECONNECT_S``)."""

    def __init__(self, url: str, *, system: int, component: int) -> None:
        super().__init__(url, system=system, component=component)
        self._addr = _host_port(url, urllib.parse.urlsplit(url))

    def _connect(self, timeout_s: float) -> bool:
        try:
            sock = socket.create_connection(self._addr, timeout=max(timeout_s, 0.05))
        except OSError:
            return False
        sock.settimeout(None)
        self._adopt(sock)
        return True

    def _retry_s(self) -> float:
        return _RECONNECT_S

    def _close(self) -> None:
        self._drop_peer()


class UdpLink(MavlinkLink):
    """``udpin://HOST:PORT`` (bind; answer the last sender) or ``udp://HOST:PORT`` (send
    there from an ephemeral port; its answers come back to that port)."""

    def __init__(self, url: str, *, system: int, component: int) -> None:
        super().__init__(url, system=system, component=component)
        parts = urllib.parse.urlsplit(url)
        host, port = _host_port(url, parts)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._peer_addr: tuple[str, int] | None = None
        self._listening = parts.scheme == "udpin"
        self._early = b""  # the datagram that found the peer, parsed by the next read
        try:
            if self._listening:
                self._sock.bind((host, port))
            else:
                self._sock.bind(("0.0.0.0" if host != "127.0.0.1" else host, 0))
                self._peer_addr = (host, port)
        except OSError as exc:
            self._sock.close()
            raise OSError(exc.errno, f"MAVLink link {url}: cannot bind UDP {host}:{port} "
                          f"({exc.strerror})") from exc
        self.port = int(self._sock.getsockname()[1])

    @property
    def connected(self) -> bool:
        return self._peer_addr is not None

    def _connect(self, timeout_s: float) -> bool:
        """``udpin://`` waits for the first datagram (``udp://`` knows its peer from the
        start: its generation stays 0)."""
        self._early = self._recv_from(timeout_s)
        return self.connected

    def _recv_from(self, timeout_s: float) -> bytes:
        try:
            ready, _, _ = select.select([self._sock], [], [], timeout_s)
            if not ready:
                return b""
            data, addr = self._sock.recvfrom(65536)
        except (OSError, ValueError):
            return b""
        if self._listening and self._peer_addr != (addr[0], addr[1]):
            with self._send_lock:
                self._peer_addr = (addr[0], addr[1])
                self._found()
        return data

    def _read(self, timeout_s: float) -> bytes | None:
        early, self._early = self._early, b""
        return early + self._recv_from(0.0 if early else timeout_s)

    def _write(self, data: bytes) -> bool:
        if self._peer_addr is None:
            return False
        try:
            self._sock.sendto(data, self._peer_addr)
        except OSError:
            return False
        return True

    def _drop_peer(self) -> None:
        if self._listening:
            self._peer_addr = None

    def _close(self) -> None:
        self._sock.close()


class SerialLink(MavlinkLink):
    """``serial:///dev/ttyACM0?baud=921600`` (pyserial; ``baud`` defaults to 921600, the
    rate PX4's HITL runs on USB): opened, and opened again after the device drops."""

    def __init__(self, url: str, *, system: int, component: int) -> None:
        super().__init__(url, system=system, component=component)
        parts = urllib.parse.urlsplit(url)
        query = urllib.parse.parse_qs(parts.query)
        unknown = sorted(set(query) - {"baud"})
        if unknown or not parts.path:
            raise ValueError(f"MAVLink link {url!r}: expected serial:///DEVICE?baud=N, got "
                             f"options {unknown}" if unknown else
                             f"MAVLink link {url!r}: expected serial:///DEVICE?baud=N")
        try:
            self.baud = int(query.get("baud", ["921600"])[-1])
        except ValueError:
            raise ValueError(f"MAVLink link {url!r}: baud must be an integer") from None
        self.device = parts.path
        self._port: Any = None

    @property
    def connected(self) -> bool:
        return self._port is not None

    def _connect(self, timeout_s: float) -> bool:
        import serial

        try:
            port = serial.Serial(self.device, self.baud, timeout=0, write_timeout=1.0)
        except (OSError, ValueError, serial.SerialException):
            return False
        with self._send_lock:
            self._port = port
            self._found()
        return True

    def _retry_s(self) -> float:
        return _RECONNECT_S

    def _read(self, timeout_s: float) -> bytes | None:
        port = self._port
        if port is None:
            return None
        try:
            ready, _, _ = select.select([port.fileno()], [], [], timeout_s)
            if not ready:
                return b""
            data = port.read(65536)
        except (OSError, ValueError, TypeError):
            return None
        return bytes(data) if data else None

    def _write(self, data: bytes) -> bool:
        port = self._port
        if port is None:
            return False
        try:
            port.write(data)
        except (OSError, ValueError):  # pyserial's exceptions are OSErrors
            return False
        return True

    def _drop_peer(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def _close(self) -> None:
        self._drop_peer()
