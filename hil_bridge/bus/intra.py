"""Composition: nodes of one process deliver messages to each other without the transport, as
ROS 2's intra-process communication does for the components of one container.

A process *composes* a bus (:func:`compose`, before its nodes are built: the launch's node host
does it for a container of several nodes, ``docs/launch.md``). Every
:class:`~hil_bridge.bus.node.Node` then made on that bus URL registers its subscriptions here,
and each of its publishers:

1. encodes the message and publishes it on the transport as before, so every other process
   (recorder, monitor, topic tools, nodes elsewhere) sees the same frames;
2. hands the message object itself, with its :class:`~hil_bridge.bus.codec.Header` and payload
   frame, to each subscription of the topic in this process
   (:meth:`~hil_bridge.bus.executor.Executor.deliver_local`): nothing is decoded, and when the
   subscriber's executor is idle its callback runs at once on the publishing thread (the reply
   to a lockstep frame leaves from the thread that ticked), else the delivery queues with the
   QoS of the subscription (keep-last depth, ``max_age_s``, acknowledgement of ``COMMAND``).

**A topic an exclusive publisher of the process publishes is heard from the process only**: a
publisher made ``exclusive=True`` says it is the topic's only one on the bus (the server's
``/clock``, states, 6-DoF states and neighbour lists; the surfaces of a firmware node that
flies its vehicle, the ArduPilot node on SITL's PWM and the PX4 node; every node's
acknowledgements, each message being acknowledged once), and while it lives the process's
subscriptions of its topic hold no transport subscription, so the copy of what they were
handed does not come back to wake them. Any other topic is heard from everywhere: a composed
server hears the hold surfaces of the SITL node beside it and those a DroneCAN node sends from
its own process. A copy that comes back (any topic a node here publishes without owning it;
one in flight while a subscription let go) is dropped before it is decoded: a composed node's
``src`` carries this process's tag (:func:`own_tag`) and its executor skips frames whose
header holds it (counted as ``loopback``). A latched publisher's last message is handed to a
subscription made after it, in this process, as the transport re-sends it to a remote one.
Messages handed over are shared, not copied: subscribers treat them (and their arrays) as
read-only, as every callback already must with a keep-last queue.

This module imports nothing of the bus; the node and its publishers use it.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["IntraBus", "compose", "composed", "intra_bus", "own_tag", "release"]

_lock = threading.Lock()
_buses: dict[str, IntraBus] = {}
_tag: tuple[int, str] | None = None


def own_tag() -> str:
    """This process's publisher tag (``pid.c`` + 8 random hex digits; made again in a forked
    child): the ``src`` of a composed node is ``name#TAG.N``."""
    global _tag
    pid = os.getpid()
    with _lock:
        if _tag is None or _tag[0] != pid:
            _tag = (pid, f"{pid:x}.c{os.urandom(4).hex()}")
        return _tag[1]


#: one local delivery target: the subscriber executor's ``deliver(sub, header, msg, payload)``
Deliver = Callable[[Any, Any, Any, bytes], None]
#: a subscription's hold on the transport: ``attach(True)`` subscribes it, ``attach(False)``
#: lets it go
Attach = Callable[[bool], None]


class IntraBus:
    """The subscriptions and publishers of one composed bus URL in this process."""

    def __init__(self, url: str) -> None:
        self.url = url
        self._lock = threading.Lock()
        #: topic -> ((deliver, subscription), ...): replaced, never mutated (read without lock)
        self._routes: dict[str, tuple[tuple[Deliver, Any], ...]] = {}
        #: topic -> the transport holds of its subscriptions here
        self._attach: dict[str, list[tuple[Any, Attach]]] = {}
        #: topic -> its publishers here (a latched one's ``last_local()`` goes to late joiners)
        self._publishers: dict[str, list[Any]] = {}
        #: topic -> its exclusive publishers here (the topic's only ones on the bus)
        self._exclusive: dict[str, list[Any]] = {}

    def route(self, topic: str) -> tuple[tuple[Deliver, Any], ...]:
        """Where a message on ``topic`` goes in this process (empty: nowhere)."""
        return self._routes.get(topic, ())

    def add_subscription(self, topic: str, deliver: Deliver, sub: Any, attach: Attach) -> None:
        """Route ``topic`` to ``sub`` too, and hold the transport for it (``attach(True)``)
        unless an exclusive publisher of it is here; a latched publisher's last message is
        handed to it."""
        with self._lock:
            self._routes[topic] = (*self._routes.get(topic, ()), (deliver, sub))
            self._attach.setdefault(topic, []).append((sub, attach))
            pubs = list(self._publishers.get(topic, ()))
            if not self._exclusive.get(topic):
                attach(True)
        for pub in pubs:
            item = pub.last_local() if pub.qos.latched else None
            if item is not None:
                deliver(sub, *item)

    def add_publisher(self, topic: str, publisher: Any, *, exclusive: bool = False) -> None:
        """A publisher of ``topic`` here; the first ``exclusive`` one (the topic's only
        publisher on the bus) lets the transport go for the topic's subscriptions here: what
        they hear of it comes in-process."""
        with self._lock:
            self._publishers.setdefault(topic, []).append(publisher)
            if exclusive:
                owners = self._exclusive.setdefault(topic, [])
                owners.append(publisher)
                if len(owners) == 1:
                    for _, attach in self._attach.get(topic, ()):
                        attach(False)

    def remove_node(self, subs: list[Any], publishers: list[Any]) -> None:
        """Forget a stopped node's subscriptions and publishers; a topic whose exclusive
        publisher here went has its subscriptions here hold the transport again."""
        gone = {id(s) for s in subs}
        with self._lock:
            for topic, targets in list(self._routes.items()):
                kept = tuple(t for t in targets if id(t[1]) not in gone)
                if kept:
                    self._routes[topic] = kept
                else:
                    del self._routes[topic]
            for holds in self._attach.values():
                holds[:] = [h for h in holds if id(h[0]) not in gone]
            for topic, pubs in list(self._publishers.items()):
                pubs[:] = [p for p in pubs if p not in publishers]
                if not pubs:
                    del self._publishers[topic]
            for topic, owners in list(self._exclusive.items()):
                owners[:] = [p for p in owners if p not in publishers]
                if not owners:
                    del self._exclusive[topic]
                    for _, attach in self._attach.get(topic, ()):
                        attach(True)


def compose(url: str) -> IntraBus:
    """Compose bus ``url`` in this process: nodes made on it from now on deliver to each other
    in-process (module docstring). Idempotent."""
    with _lock:
        bus = _buses.get(url)
        if bus is None:
            bus = _buses[url] = IntraBus(url)
        return bus


def release(url: str) -> None:
    """Stop composing ``url`` (nodes already made keep their routes)."""
    with _lock:
        _buses.pop(url, None)


def intra_bus(url: str) -> IntraBus | None:
    """The composed bus ``url`` of this process, or None."""
    return _buses.get(url)


def composed(url: str) -> bool:
    """Whether this process composes ``url``."""
    return url in _buses
