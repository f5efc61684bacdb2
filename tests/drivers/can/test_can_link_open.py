"""A CAN bus that cannot be opened is retried with back-off and said once, never silently."""

from __future__ import annotations

import logging
import time

import pytest

from drivers.can.bus import CanBusConfig, CanLink, LinkPolicy


def test_unopenable_bus_warns_once_and_counts_every_retry(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # socketcan on a channel that does not exist: OSError from the kernel (or no AF_CAN at all)
    config = CanBusConfig(interface="socketcan", channel="echoloop-missing0")
    caplog.set_level(logging.WARNING, logger="drivers.can.bus")
    link = CanLink(config, policy=LinkPolicy(reopen_backoff_s=0.001, max_backoff_s=0.002))
    try:
        deadline = time.monotonic() + 10.0
        while link.stats().get("open_failures", 0) < 3:
            assert time.monotonic() < deadline, link.stats()
            assert link.recv(timeout=0.005) is None
        stats = link.stats()
    finally:
        link.close()
    assert stats["state"] == "down"
    assert stats["open_failures"] >= 3
    warnings = [r for r in caplog.records if "cannot be opened" in r.getMessage()]
    assert len(warnings) == 1
    assert "socketcan:echoloop-missing0" in warnings[0].getMessage()
