"""CAN over UDP multicast (ArduPilot SITL's CAN bus, ``mcast:N``), in this process.

The wire, as ArduPilot's ``AP_HAL_SITL/CAN_Multicast.cpp`` and the ``dronecan`` package's
``mcast`` driver have it: group ``239.65.82.N`` (N the bus), UDP port 57732, one datagram per
CAN frame: magic 0x2934 (u16), a CRC-16-CCITT of what follows (u16), flags (u16, bit 0 CAN FD),
the 32-bit frame id (bit 31 set for an extended id) and the data, little endian.

:class:`McastDriver` is a ``dronecan`` driver (``AbstractDriver``: ``send``, ``receive``,
``close``) on two sockets of this process: it needs no helper process (the package's own
``mcast`` driver runs one that polls every 10 ms and outlives a killed parent), answers within
the time a datagram takes, and ``fileno()`` lets a caller wait on it. A datagram that is not a
frame (short, another magic, a CRC that fails) is dropped and counted (``bad_datagrams``);
a frame this driver sent itself (multicast loops back) is not received. The group's hop limit
is 0: frames never leave the host.
"""

from __future__ import annotations

import binascii
import select
import socket
import struct
import threading
from typing import Any

from dronecan.driver.common import AbstractDriver, CANFrame

__all__ = ["MCAST_PORT", "McastDriver"]

MCAST_PORT = 57732
_MAGIC = 0x2934
_FLAG_CANFD = 0x0001
_EFF = 1 << 31


def _crc(data: bytes) -> int:
    """The datagram's CRC-16-CCITT (initial 0xFFFF, polynomial 0x1021: the ``dronecan``
    package's ``crc16_from_bytes``), in C: the package's runs in Python, 10 µs a frame."""
    return binascii.crc_hqx(data, 0xFFFF)


class McastDriver(AbstractDriver):
    """The ``dronecan`` driver of bus ``N`` of CAN over UDP multicast (module docstring)."""

    def __init__(self, bus: int = 0, **_: Any) -> None:
        super().__init__()
        if not 0 <= bus <= 255:
            raise ValueError(f"mcast bus: expected 0..255, got {bus}")
        self.bus = bus
        self.group = f"239.65.82.{bus}"
        self._closed = False
        self._rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        self._tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        try:
            self._rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._rx.bind((self.group, MCAST_PORT))
            mreq = struct.pack("4s4s", socket.inet_aton(self.group), socket.inet_aton("0.0.0.0"))
            self._rx.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
            self._tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
            self._tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            self._tx.connect((self.group, MCAST_PORT))
        except OSError as exc:
            self.close()
            raise OSError(exc.errno, f"mcast:{bus}: cannot join {self.group}:{MCAST_PORT} "
                          f"({exc.strerror})") from exc
        self._rx.setblocking(False)
        self._own_port = self._tx.getsockname()[1]
        self._lock = threading.Lock()
        self.counts = {"frames_in": 0, "frames_out": 0, "bad_datagrams": 0}

    def fileno(self) -> int:
        """The receiving socket (readable when a frame may be there)."""
        return self._rx.fileno()

    def send(self, message_id: int, message: bytes, extended: bool = False,
             canfd: bool = False) -> None:
        frame = CANFrame(message_id, message, extended, canfd=canfd)
        self._tx_hook(frame)
        body = struct.pack("<HI", _FLAG_CANFD if canfd else 0,
                           message_id | (_EFF if extended else 0)) + bytes(message)
        with self._lock:
            self._tx.send(struct.pack("<HH", _MAGIC, _crc(body)) + body)
            self.counts["frames_out"] += 1

    def send_frame(self, frame: CANFrame) -> None:
        self.send(frame.id, frame.data, frame.extended, frame.canfd)

    def receive(self, timeout: float | None = None) -> CANFrame | None:
        """The next frame within ``timeout`` s (None: wait for one), or None."""
        while True:
            try:
                data, addr = self._rx.recvfrom(128)
            except BlockingIOError:
                if timeout == 0:
                    return None
                ready, _, _ = select.select([self._rx], [], [], timeout)
                if not ready:
                    return None
                timeout = 0 if timeout is not None else None
                continue
            except OSError:
                return None
            if addr[1] == self._own_port:
                continue  # our own frame, looped back
            frame = self._parse(data)
            if frame is not None:
                self._rx_hook(frame)
                return frame

    def _parse(self, data: bytes) -> CANFrame | None:
        if len(data) < 10:
            self.counts["bad_datagrams"] += 1
            return None
        magic, crc, flags, message_id = struct.unpack_from("<HHHI", data)
        if magic != _MAGIC or crc != _crc(data[4:]):
            self.counts["bad_datagrams"] += 1
            return None
        self.counts["frames_in"] += 1
        return CANFrame(message_id & 0x1FFFFFFF, bytearray(data[10:]), bool(message_id & _EFF),
                        canfd=bool(flags & _FLAG_CANFD))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._rx.close()
        self._tx.close()
