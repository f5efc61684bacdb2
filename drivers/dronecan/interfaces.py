"""CAN interfaces by URL, one table: what a DroneCAN node of echoloop can sit on.

==================================  ======================================================
``mcast:N``                         CAN over UDP multicast, bus N (ArduPilot SITL's CAN,
                                    :class:`~drivers.dronecan.mcast.McastDriver`): no
                                    adapter, no root
``socketcan:can0`` (or ``can0``)    a Linux SocketCAN interface (a USB-CAN adapter, vcan)
``slcan:/dev/ttyACM0?baud=1000000``  an SLCAN serial adapter (CANable, Zubax Babel, ...)
==================================  ======================================================

``open_can(url)`` returns a ``dronecan`` driver; the backends of ``socketcan`` and
``slcan`` are the ``dronecan`` package's own (imported when used).
"""

from __future__ import annotations

import importlib
import urllib.parse
from typing import Any

__all__ = ["SCHEMES", "open_can"]

#: scheme -> "module:Class" of its driver
SCHEMES = {
    "mcast": "drivers.dronecan.mcast:McastDriver",
    "socketcan": "dronecan.driver.socketcan:SocketCAN",
    "slcan": "dronecan.driver.slcan:SLCAN",
}


def open_can(url: str) -> Any:
    """The ``dronecan`` driver for ``url`` (module docstring); ``ValueError`` naming the
    known schemes otherwise."""
    scheme, _, rest = url.partition(":")
    if not rest and scheme and scheme not in SCHEMES:  # a bare interface name: SocketCAN
        scheme, rest = "socketcan", url
    target = SCHEMES.get(scheme)
    if target is None:
        raise ValueError(f"CAN interface {url!r}: unknown scheme {scheme!r}; expected one of "
                         f"{sorted(SCHEMES)} (or a SocketCAN interface name such as can0)")
    module, cls = target.split(":")
    driver: Any = getattr(importlib.import_module(module), cls)
    if scheme == "mcast":
        try:
            bus = int(rest or "0")
        except ValueError:
            raise ValueError(f"CAN interface {url!r}: expected mcast:N, N a bus number") from None
        return driver(bus)
    if scheme == "slcan":
        parts = urllib.parse.urlsplit("slcan://" + rest.removeprefix("//"))
        query = urllib.parse.parse_qs(parts.query)
        try:
            baud = int(query.get("baud", ["1000000"])[-1])
        except ValueError:
            raise ValueError(f"CAN interface {url!r}: baud must be an integer") from None
        return driver(parts.path, baudrate=baud, bitrate=1000000)
    return driver(rest)
