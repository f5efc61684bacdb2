"""Bus fixtures, used by the conftests of ``bus/`` and ``recording/``: ``bus_url`` is one fresh
bus per test, parametrised over ``mem``, ``zmq`` and ``composed`` (ZeroMQ, with this process
composing it: the nodes of a test deliver to each other in-process, :mod:`hil_bridge.bus.intra`,
and everything else must hold as it does between processes); an autouse guard fails a test that
leaves a ZeroMQ socket or a ``mem://`` endpoint open."""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterator

import pytest
import zmq

from hil_bridge.bus import intra
from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.transport import mem

_names = itertools.count()


@contextlib.contextmanager
def open_bus(kind: str) -> Iterator[str]:
    """A bus URL of ``kind``: an unused ``mem://`` channel, or a proxy on free loopback ports
    (composed in this process for ``composed``)."""
    if kind == "mem":
        yield f"mem://test{next(_names)}"
        return
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as proxy:
        if kind == "zmq":
            yield proxy.url
            return
        intra.compose(proxy.url)
        try:
            yield proxy.url
        finally:
            intra.release(proxy.url)


@pytest.fixture(params=["mem", "zmq", "composed"])
def bus_url(request: pytest.FixtureRequest) -> Iterator[str]:
    """A bus URL of each kind (:func:`open_bus`)."""
    with open_bus(request.param) as url:
        yield url


@pytest.fixture(autouse=True)
def _no_socket_leaks() -> Iterator[None]:
    """Every transport the test opened must be closed when it ends (python-can's guard)."""
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
    before = {id(s) for s in ctx._sockets if not s.closed}
    channels_before = set(mem._CHANNELS)
    yield
    leaked = [s for s in ctx._sockets if not s.closed and id(s) not in before]
    assert not leaked, f"test left {len(leaked)} ZeroMQ socket(s) open"
    left = set(mem._CHANNELS) - channels_before
    assert not left, f"test left mem:// endpoints open on {sorted(left)}"
