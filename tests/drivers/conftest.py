"""Fixtures of the driver tests: ``domain``, a numbered echoloop domain of this test's own (its
ports, ``mcast:`` bus and SITL instance), claimed among 20..79 so that two suites at once
never share one."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from hil_bridge.bus.domain import Domain, claim_first_free


@pytest.fixture
def domain() -> Iterator[Domain]:
    with claim_first_free(Domain(int.from_bytes(os.urandom(1)) % 60 + 20)) as (dom, _):
        yield dom
