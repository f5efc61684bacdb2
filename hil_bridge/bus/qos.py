"""Named QoS profiles (ROS 2 vocabulary): ``SENSOR``, ``COMMAND``, ``LATCHED``.

- ``SENSOR`` — best effort, keep-last ``depth`` 5 per subscription: a slow callback sees the
  newest messages; older ones are dropped and counted.
- ``COMMAND`` — reliable: every message is acknowledged on ``<topic>/ack`` (a
  :class:`~hil_bridge.bus.messages.CmdAck` naming publisher ``src`` and ``seq``); the publisher
  re-sends every ``retry_period_s`` until acked or ``ack_timeout_s`` passes (then counts it
  ``ack_failed``); subscribers suppress duplicates by ``(src, seq)``.
- ``LATCHED`` — the publisher keeps its last message and re-sends it whenever a new
  subscription to its topic appears (transient-local durability), so late joiners get it;
  existing subscribers drop the repeat as a duplicate ``seq``.

``max_age_s`` (any profile, subscriptions only) bounds how old a delivered message may be, in
sim time against the subscribing node's clock: an older one is dropped (counted ``stale``) and
the receive queue of its topic is reset, dropping the backlog behind it, so a flooded or stalled
topic resumes with its newest messages. Use it where the node's clock follows the publisher's
(``follow_bus_clock``), as the CAN adapter's states do.

Publisher and subscriber need not use the same profile; ``COMMAND`` acks are sent by
``COMMAND`` subscribers, and ``LATCHED`` re-sends come from ``LATCHED`` publishers.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["COMMAND", "LATCHED", "PROFILES", "SENSOR", "QoSProfile", "qos_profile"]


@dataclass(frozen=True, slots=True)
class QoSProfile:
    """Delivery policy of one publisher or subscription (see the module docstring)."""

    name: str
    depth: int = 5
    reliable: bool = False
    latched: bool = False
    ack_timeout_s: float = 1.0
    retry_period_s: float = 0.05
    #: subscriptions: drop a message whose ``stamp_ns`` is older than the node's clock by more
    #: than this (sim seconds), and reset its receive queue (None: no limit)
    max_age_s: float | None = None

    def __post_init__(self) -> None:
        if self.depth < 1:
            raise ValueError(f"QoSProfile.depth must be >= 1, got {self.depth}")
        if self.max_age_s is not None and not self.max_age_s > 0:
            raise ValueError(f"QoSProfile.max_age_s must be > 0 or None, got {self.max_age_s}")
        if not self.retry_period_s > 0 or not self.ack_timeout_s > 0:
            raise ValueError(
                "QoSProfile.retry_period_s and ack_timeout_s must be > 0, got "
                f"{self.retry_period_s} and {self.ack_timeout_s}"
            )


SENSOR = QoSProfile("sensor", depth=5)
COMMAND = QoSProfile("command", depth=10, reliable=True)
LATCHED = QoSProfile("latched", depth=1, latched=True)

PROFILES: dict[str, QoSProfile] = {p.name: p for p in (SENSOR, COMMAND, LATCHED)}


def qos_profile(qos: QoSProfile | str) -> QoSProfile:
    """A profile, or the named one (``ValueError`` listing the names)."""
    if isinstance(qos, QoSProfile):
        return qos
    try:
        return PROFILES[qos]
    except KeyError:
        raise ValueError(
            f"unknown QoS profile {qos!r}; expected one of {sorted(PROFILES)}"
        ) from None
