"""A CAN bus shared by the processes of one host: python-can's ``udp_multicast``, on loopback.

python-can's :class:`~can.interfaces.udp_multicast.UdpMulticastBus` joins its group on the
default route's interface and sends with a hop limit of 1, so its frames (and the IGMP reports
of the join) reach the local network. A launch's nodes only need to meet on their own host, so
:class:`LoopbackMulticastBus` keeps everything on ``lo``: the group is joined on 127.0.0.1,
frames leave through 127.0.0.1 with a time-to-live of 0, and the receiving socket is bound to
the group (it receives nothing else). It speaks python-can's udp_multicast wire format (msgpack'd
messages), so tools of python-can read it.

:meth:`hil_bridge.bus.domain.Domain.can_multicast` gives each domain its own group and port.
Multicast with loop-back on hands a sender its own frames back, and a bus carrying a state's
four frames at 250 Hz would wake, read and unpack each of them only to drop it. So a bus sends
from a socket of its own (an ephemeral port on 127.0.0.1, which joins no group), and its
receiving socket carries a socket filter (classic BPF, ``SO_ATTACH_FILTER``) that drops, in the
kernel, every datagram whose UDP source port is that port: a bus never sees its own frames, as
on a ``virtual`` bus, and every other bus of the group, in this process or another, sees them.
"""

from __future__ import annotations

import ctypes
import socket
import struct
from typing import Any

import can
from can import BusABC, CanInitializationError
from can.bus import CanProtocol
from can.interfaces.udp_multicast.bus import GeneralPurposeUdpMulticastBus, UdpMulticastBus

__all__ = ["LoopbackMulticastBus"]

_LOOPBACK = socket.inet_aton("127.0.0.1")


#: ``SO_ATTACH_FILTER`` (Linux ``asm-generic/socket.h``; the ``socket`` module has no name
#: for it)
SO_ATTACH_FILTER = 26


def _drop_from_port(port: int) -> tuple[bytes, Any]:
    """A classic BPF program for a UDP socket (the filter sees the datagram from its UDP header):
    drop what comes from source ``port``, keep the rest. Returns the ``sock_fprog`` to attach
    and the buffer it points into (keep it alive until the filter is attached)."""
    program = [(0x28, 0, 0, 0),           # ldh [0]: the UDP source port
               (0x15, 0, 1, port),        # jeq #port: next, else skip one
               (0x06, 0, 0, 0),           # ret #0: drop
               (0x06, 0, 0, 0xFFFFFFFF)]  # ret #-1: the whole datagram
    code = ctypes.create_string_buffer(b"".join(struct.pack("HBBI", *op) for op in program))
    return struct.pack("HL", len(program), ctypes.addressof(code)), code


class _LoopbackSocket(GeneralPurposeUdpMulticastBus):
    """python-can's multicast socket handler with the sockets kept on ``lo`` (IPv4 only): one
    bound to the group that receives, one that sends (module docstring)."""

    _tx: socket.socket

    def _create_socket(self, address_family: socket.AddressFamily) -> socket.socket:
        if address_family != socket.AF_INET:
            raise OSError(f"{self.group}: the loopback CAN bus takes an IPv4 group")
        opened: list[socket.socket] = []
        try:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            opened.append(sock)
            tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            opened.append(tx)
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, _LOOPBACK)
            tx.bind(("127.0.0.1", 0))
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            fprog, _code = _drop_from_port(tx.getsockname()[1])
            sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)
            self.timestamp_nanosecond = False
            sock.bind((self.group, self.port))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                            socket.inet_aton(self.group) + _LOOPBACK)
        except OSError as exc:  # neither socket outlives a bus that did not open
            for opened_socket in opened:
                opened_socket.close()
            raise CanInitializationError(
                f"cannot open the loopback CAN bus {self.group}:{self.port}: {exc}") from exc
        self._tx = tx
        return sock

    def send(self, data: bytes, timeout: float | None = None) -> None:
        """python-can's send (the same errors), from the sending socket."""
        if timeout != self._last_send_timeout:
            self._last_send_timeout = timeout
            self._tx.settimeout(timeout)
        try:
            if self._tx.sendto(data, self._send_destination) < len(data):
                raise TimeoutError()
        except TimeoutError:
            raise can.CanTimeoutError() from None
        except OSError as error:
            raise can.CanOperationError("failed to send via socket") from error

    def shutdown(self) -> None:
        super().shutdown()
        self._tx.close()


class LoopbackMulticastBus(UdpMulticastBus):
    """``UdpMulticastBus`` on loopback only: ``channel`` an IPv4 multicast group, ``port``."""

    def __init__(self, channel: str, port: int, fd: bool = True, **kwargs: Any) -> None:
        BusABC.__init__(self, channel, **kwargs)
        self._multicast = _LoopbackSocket(channel, port, hop_limit=0)
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
