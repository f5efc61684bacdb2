"""Bus transports behind one factory: :func:`open_transport` picks a backend by URL scheme.

``BACKENDS`` maps scheme → ``"module:Class"`` (imported lazily, as python-can's backend table):

- ``mem://NAME[?depth=N]`` — in-process channel for tests (:mod:`hil_bridge.bus.transport.mem`);
- ``tcp://HOST:PORT[?sub=URL&hwm=N&curve_server=F&curve_client=F]`` and ``ipc://PATH[?...]`` —
  ZeroMQ through the XSUB/XPUB proxy (:mod:`hil_bridge.bus.transport.zmq`);
- ``replay://PATH.mcap[?rate=R&loop=1]`` — a recording played as a read-only bus
  (:mod:`hil_bridge.recording.replay_transport`).
"""

from __future__ import annotations

import importlib
from urllib.parse import urlsplit

from hil_bridge.bus.transport.base import Frames, Transport, sync_open

__all__ = ["BACKENDS", "Frames", "Transport", "backend_class", "open_transport", "sync_open"]

BACKENDS: dict[str, str] = {
    "mem": "hil_bridge.bus.transport.mem:MemTransport",
    "tcp": "hil_bridge.bus.transport.zmq:ZmqTransport",
    "ipc": "hil_bridge.bus.transport.zmq:ZmqTransport",
    "replay": "hil_bridge.recording.replay_transport:ReplayTransport",
}


def backend_class(url: str) -> type[Transport]:
    """The :class:`Transport` subclass serving ``url``'s scheme (``ValueError`` if unknown)."""
    if not isinstance(url, str):
        raise TypeError(f"bus URL must be a str, got {type(url).__name__}")
    scheme = urlsplit(url).scheme
    try:
        target = BACKENDS[scheme]
    except KeyError:
        raise ValueError(
            f"unknown bus URL scheme {scheme!r} in {url!r}; expected one of {sorted(BACKENDS)}"
        ) from None
    module_name, _, class_name = target.partition(":")
    cls: type[Transport] = getattr(importlib.import_module(module_name), class_name)
    return cls


def open_transport(url: str) -> Transport:
    """Open one endpoint of the bus named by ``url`` (see the module docstring)."""
    return backend_class(url)(url)
