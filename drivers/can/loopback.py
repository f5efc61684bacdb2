"""A CAN bus shared by the processes of one host: python-can's ``udp_multicast``, on loopback.

python-can's :class:`~can.interfaces.udp_multicast.UdpMulticastBus` joins its group on the
default route's interface and sends with a hop limit of 1, so its frames (and the IGMP reports
of the join) reach the local network. A launch's nodes only need to meet on their own host, so
:class:`LoopbackMulticastBus` keeps everything on ``lo``: the group is joined on 127.0.0.1,
frames leave through 127.0.0.1 with a time-to-live of 0, and the socket is bound to the group
(it receives nothing else). It speaks python-can's udp_multicast wire format (msgpack'd
messages), so tools of python-can read it.

:meth:`hil_bridge.bus.domain.Domain.can_multicast` gives each domain its own group and port.
Like every multicast socket with loop-back on, the bus hands a sender its own frames back:
:class:`~drivers.can.bus.CanLink` tags what it sends and drops its own frames on receive.
"""

from __future__ import annotations

import socket
from typing import Any

from can import BusABC, CanInitializationError
from can.bus import CanProtocol
from can.interfaces.udp_multicast.bus import GeneralPurposeUdpMulticastBus, UdpMulticastBus

__all__ = ["LoopbackMulticastBus"]

_LOOPBACK = socket.inet_aton("127.0.0.1")


class _LoopbackSocket(GeneralPurposeUdpMulticastBus):
    """python-can's multicast socket handler with the socket kept on ``lo`` (IPv4 only)."""

    def _create_socket(self, address_family: socket.AddressFamily) -> socket.socket:
        if address_family != socket.AF_INET:
            raise OSError(f"{self.group}: the loopback CAN bus takes an IPv4 group")
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, _LOOPBACK)
            self.timestamp_nanosecond = False
            sock.bind((self.group, self.port))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                            socket.inet_aton(self.group) + _LOOPBACK)
        except OSError as exc:
            sock.close()
            raise CanInitializationError(
                f"cannot open the loopback CAN bus {self.group}:{self.port}: {exc}") from exc
        return sock


class LoopbackMulticastBus(UdpMulticastBus):
    """``UdpMulticastBus`` on loopback only: ``channel`` an IPv4 multicast group, ``port``."""

    def __init__(self, channel: str, port: int, fd: bool = True, **kwargs: Any) -> None:
        BusABC.__init__(self, channel, **kwargs)
        self._multicast = _LoopbackSocket(channel, port, hop_limit=0)
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
