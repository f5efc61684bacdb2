"""Bus fixtures: ``bus_url`` is one fresh bus per test, parametrised over ``mem`` and ``zmq``."""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import pytest

from hil_bridge.proxy import Proxy

_names = itertools.count()


@pytest.fixture(params=["mem", "zmq"])
def bus_url(request: pytest.FixtureRequest) -> Iterator[str]:
    """A bus URL: an unused ``mem://`` channel, or a proxy on free loopback ports."""
    if request.param == "mem":
        yield f"mem://test{next(_names)}"
        return
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as proxy:
        yield proxy.url
