"""Nodes: rclpy-shaped publishers, subscriptions and timers over one bus transport.

A :class:`Node` opens its transport when constructed (so publishers and subscriptions made in
``__init__`` are live at once) and runs two worker threads after :meth:`Node.start`: its
executor (:mod:`hil_bridge.bus.executor`: who receives, who runs callbacks and timers, one at a
time, and what a slow callback or a flood costs).

A frame that does not decode is dropped and counted as ``decode_errors``; publisher ``seq``
gaps are counted as ``dropped`` (the message was lost upstream, e.g. at a full queue). An
exception in a callback, a timer or reception is counted (``callback_errors``) and reported to
the node's :attr:`Node.faults` (:mod:`hil_bridge.bus.faults`); it never ends a thread, and
:meth:`Node.failure` names it.

:class:`Publisher`, :class:`Subscription` and :class:`Timer` live in
:mod:`hil_bridge.bus.endpoints` (importable from here too).

The *launchable* contract (``Cls(name, *, bus, **params)``, ``start()``, ``stop()``,
``stats()``, ``failure(final=False)``) is met by :class:`Node` and by subclasses that add their
own parameters; a subclass's own threads report to the same :attr:`Node.faults`.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import os
import re
import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any, TypeVar

from hil_bridge.bus.clock import SimClock, default_clock
from hil_bridge.bus.codec import Header, validate_topic
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.endpoints import Publisher, Subscription, Timer
from hil_bridge.bus.executor import DECODE_LOG_PERIOD_S, Executor
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.intra import intra_bus, own_tag
from hil_bridge.bus.messages import Clock, CmdAck, Diagnostics, Message
from hil_bridge.bus.qos import LATCHED, SENSOR, QoSProfile, qos_profile
from hil_bridge.bus.transport import Transport, open_transport

__all__ = ["DECODE_LOG_PERIOD_S", "Node", "Publisher", "Subscription", "Timer"]

M = TypeVar("M", bound=Message)

_NODE_IDS = itertools.count()
_NAME_RE = re.compile(r"^[A-Za-z0-9_]+$")


def _topic_counters() -> dict[str, int]:
    return {
        "sent": 0,
        "received": 0,
        "dropped": 0,
        "duplicates": 0,
        "epochs": 0,
        "stale": 0,
        "decode_errors": 0,
        "callback_errors": 0,
        "retransmits": 0,
        "acked": 0,
        "ack_failed": 0,
        "local": 0,
    }


class Node:
    """A bus participant: ``Node(name, *, bus=None, clock=None, diagnostics_period_s=1.0,
    faults=None)``.

    ``bus`` defaults to the current domain's bus (:mod:`hil_bridge.bus.domain`).

    ``clock`` defaults to :func:`~hil_bridge.bus.clock.default_clock`. ``diagnostics_period_s``
    (wall seconds; 0 disables) sets how often ``/diagnostics`` carries :meth:`stats`.
    ``faults``: the :class:`~hil_bridge.bus.faults.Faults` its callbacks report to (default a
    new one named ``name``; a launchable that owns a node passes its own, so there is one
    record per launchable).
    Use as a context manager or call :meth:`stop` (idempotent) to close threads and sockets.
    """

    def __init__(
        self,
        name: str,
        *,
        bus: str | None = None,
        clock: SimClock | None = None,
        diagnostics_period_s: float = 1.0,
        faults: Faults | None = None,
    ) -> None:
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise ValueError(f"node name must be a non-empty [A-Za-z0-9_] string, got {name!r}")
        if diagnostics_period_s < 0:
            raise ValueError(f"diagnostics_period_s must be >= 0, got {diagnostics_period_s}")
        self.name = name
        self.bus = bus if bus is not None else current_domain().bus_url
        self.clock = clock if clock is not None else default_clock()
        #: the composed bus this node also delivers on in-process (hil_bridge.bus.intra)
        self.intra = intra_bus(self.bus)
        self.src = (f"{name}#{own_tag()}.{next(_NODE_IDS)}" if self.intra is not None else
                    f"{name}#{os.getpid():x}.{next(_NODE_IDS)}.{os.urandom(3).hex()}")
        self.diagnostics_period_s = diagnostics_period_s
        #: what went wrong in this node (its callbacks, timers, reception, its own threads)
        self.faults = faults if faults is not None else Faults(name)
        self._counters_by_topic: dict[str, dict[str, int]] = {}
        self._publishers: list[Publisher[Any]] = []
        self._ack_pubs: dict[str, Publisher[CmdAck]] = {}
        self._ack_targets: dict[str, Publisher[Any]] = {}
        self._lock = threading.RLock()
        self._next_diag = 0.0
        self._started = False
        self._stopped = False
        self._diag_pub: Publisher[Diagnostics] | None = None
        self.transport: Transport = open_transport(self.bus)
        self._executor = Executor(
            name, self.transport, self.clock, self.faults, send_ack=self._send_ack,
            periodic=self._periodic, counters=self._topic,
            own=None if self.intra is None else f"#{own_tag()}.".encode(),
        )
        self.transport.on_subscribe = self._on_remote_subscribe
        self.clock.add_listener(self._clock_stepped)

    # -- construction API (rclpy shapes) ---------------------------------------------------
    def _topic(self, topic: str) -> dict[str, int]:
        with self._lock:
            counters = self._counters_by_topic.get(topic)
            if counters is None:
                counters = self._counters_by_topic[topic] = _topic_counters()
            return counters

    def create_publisher(
        self,
        msg_type: type[M],
        topic: str,
        qos: QoSProfile | str = SENSOR,
        *,
        frame_id: str = "",
        exclusive: bool = False,
    ) -> Publisher[M]:
        """A publisher of ``msg_type`` on ``topic`` with ``qos`` (SENSOR, COMMAND or LATCHED).
        ``exclusive=True`` says it is the topic's only publisher on the bus: on a composed bus
        the topic is then heard in this process from this process only
        (:mod:`hil_bridge.bus.intra`)."""
        self._check_type(msg_type)
        validate_topic(topic)
        profile = qos_profile(qos)
        pub = Publisher(self, msg_type, topic, profile, frame_id)
        with self._lock:
            self._publishers.append(pub)
            if profile.reliable:
                self._ack_targets[topic] = pub
        if self.intra is not None:
            self.intra.add_publisher(topic, pub, exclusive=exclusive)
        if profile.reliable:
            self._add_subscription(CmdAck, f"{topic}/ack", self._on_ack, SENSOR, False, True,
                                   inline=True)
        return pub

    def create_subscription(
        self,
        msg_type: type[M],
        topic: str,
        callback: Callable[[Any], None],
        qos: QoSProfile | str = SENSOR,
        *,
        envelope: bool = False,
        priority: bool = False,
        lane: str | None = None,
        inline: bool = False,
    ) -> Subscription[M]:
        """Call ``callback(msg)`` for each ``msg_type`` message on ``topic`` (``envelope=True``:
        ``callback(Envelope)`` with topic, header and raw payload). ``priority=True`` puts the
        subscription on the control path: its callbacks run before any other queued ones.
        ``inline=True`` says the callback is short and never blocks: on a composed bus
        (:mod:`hil_bridge.bus.intra`) it may then run on the publishing thread itself.

        Every subscription has its own receive queue (its *lane*), served in turn with the
        others, so a flood on one topic cannot hold back another; messages of different lanes
        may be delivered out of their publishing order. Subscriptions made with the same
        ``lane`` name share one queue and are delivered in arrival order (use it for topics
        whose order matters to the callbacks, e.g. a state and the neighbour list of its
        step)."""
        self._check_type(msg_type)
        validate_topic(topic)
        profile = qos_profile(qos)
        if profile.reliable:
            with self._lock:
                if topic not in self._ack_pubs:
                    # exclusive: a message is acknowledged once; the acks of this process's
                    # subscriptions reach its publishers here (hil_bridge.bus.intra)
                    self._ack_pubs[topic] = self.create_publisher(CmdAck, f"{topic}/ack",
                                                                  exclusive=True)
        return self._add_subscription(msg_type, topic, callback, profile, envelope, priority,
                                      lane, inline)

    def _add_subscription(
        self,
        msg_type: type[M],
        topic: str,
        callback: Callable[[Any], None],
        qos: QoSProfile,
        envelope: bool,
        priority: bool = False,
        lane: str | None = None,
        inline: bool = False,
    ) -> Subscription[M]:
        shared = None if lane is None else self._executor.lane(lane)
        sub = Subscription(self, msg_type, topic, callback, qos, envelope, priority, shared,
                           inline)
        frame = topic.encode() + b"\0"
        self._executor.add_subscription(frame, sub)
        lane_key = None if lane is None else f"lane:{lane}"
        if self.intra is None:
            self.transport.subscribe(frame, lane=lane_key)
        else:
            self.intra.add_subscription(topic, self._executor.deliver_local, sub,
                                        functools.partial(self._hold, frame, lane_key, [False]))
        return sub

    def _hold(self, frame: bytes, lane: str | None, held: list[bool], on: bool) -> None:
        """A composed subscription's hold on the transport (:mod:`hil_bridge.bus.intra`)."""
        if on != held[0] and not self.transport.closed:
            held[0] = on
            if on:
                self.transport.subscribe(frame, lane=lane)
            else:
                self.transport.unsubscribe(frame)

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> Timer:
        """Call ``callback()`` every ``period_s`` seconds of the node's sim clock."""
        timer = Timer(self, period_s, callback)
        self._executor.add_timer(timer)
        return timer

    @staticmethod
    def _check_type(msg_type: type) -> None:
        if not (isinstance(msg_type, type) and issubclass(msg_type, Message) and msg_type.TYPE):
            raise TypeError(f"msg_type must be a registered message class, got {msg_type!r}")

    def now_ns(self) -> int:
        """The node's sim time (for ``stamp_ns``)."""
        return self.clock.now_ns()

    def follow_bus_clock(self, topic: str = "/clock") -> Subscription[Clock]:
        """Drive this node's clock from ``/clock`` (the clock must be owner-stepped); the
        subscription has priority (the control path)."""
        if not self.clock.owner_stepped:
            raise ValueError("follow_bus_clock needs a 'lockstep' or 'fast' SimClock on the node")

        def on_clock(msg: Clock) -> None:
            if msg.stamp_ns > self.clock.now_ns():
                self.clock.set_ns(msg.stamp_ns)

        # depth of SENSOR, not 1: a receive batch after a stall (another thread holding the
        # GIL) can hold several ticks; on_clock keeps the newest anyway, so none is "dropped"
        qos = dataclasses.replace(LATCHED, depth=SENSOR.depth)
        return self.create_subscription(Clock, topic, on_clock, qos, priority=True)

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> Node:
        """Start the two worker threads (non-blocking; idempotent)."""
        with self._lock:
            if self._started or self._stopped:
                if self._stopped:
                    raise RuntimeError(f"node {self.name!r} was stopped; make a new one")
                return self
            if self.diagnostics_period_s > 0 and self._diag_pub is None:
                self._diag_pub = self.create_publisher(Diagnostics, "/diagnostics")
            self._next_diag = time.monotonic() + self.diagnostics_period_s
            self._started = True
            self._executor.start()
        return self

    def stop(self) -> None:
        """Stop threads, join them and close the transport (idempotent)."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
        if self.intra is not None:
            with self._lock:
                publishers = list(self._publishers)
            self.intra.remove_node(self._executor.subscriptions(), publishers)
        self._executor.stop()
        self.clock.remove_listener(self._clock_stepped)
        self.transport.close()

    @property
    def running(self) -> bool:
        return self._started and not self._stopped

    def __enter__(self) -> Node:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def failure(self, *, final: bool = False) -> str | None:
        """Why the node failed (:meth:`hil_bridge.bus.faults.Faults.failure`), or None."""
        return self.faults.failure(final=final)

    # -- counters ----------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """``{"node", "sent", "received", "dropped", "duplicates", "decode_errors",
        "callback_errors", "retransmits", "acked", "ack_failed", "timer_overruns", "faults",
        "topics": {topic: {...}}, "transport": {...}}`` (``faults``: reports to
        :attr:`faults`, every place)."""
        with self._lock:
            topics = {t: dict(c) for t, c in self._counters_by_topic.items()}
        overruns = sum(t.overruns for t in self._executor.timers() if not t.cancelled)
        totals: dict[str, Any] = {"node": self.name}
        for key in _topic_counters():
            totals[key] = sum(c.get(key, 0) for c in topics.values())
        totals["timer_overruns"] = overruns
        totals["loopback"] = self._executor.loopback
        totals["faults"] = sum(self.faults.counts().values())
        totals["topics"] = topics
        totals["transport"] = self.transport.stats()
        return totals

    def counters(self) -> dict[str, Any]:
        """What the periodic ``/diagnostics`` is made of (the numbers, and the counters of
        ``"topics"``): :meth:`stats` here. A node whose ``stats()`` also summarises thousands of
        samples (percentiles) gives its counters alone here: the diagnostics are taken on the
        node's executor, and milliseconds of summaries there hold every callback behind them."""
        return self.stats()

    def _diagnostics(self) -> Diagnostics:
        stats = self.counters()
        counters: dict[str, int | float] = {
            k: v for k, v in stats.items() if isinstance(v, (int, float))
        }
        for topic, c in stats["topics"].items():
            for key in ("sent", "received", "dropped", "epochs", "stale", "decode_errors"):
                if c[key]:
                    counters[f"{key}:{topic}"] = c[key]
        return Diagnostics(stamp_ns=self.clock.now_ns(), node=self.name, counters=counters)

    # -- internals ---------------------------------------------------------------------------
    def _clock_stepped(self) -> None:
        """The clock moved: only timers run on sim time (diagnostics and retransmissions on
        the wall clock), so the executor is woken only when there are timers; a server
        stepping its clock at 250 Hz would otherwise wake a worker thread every tick."""
        if self._executor.has_timers:
            self._executor.wake()

    def _wake_exec(self) -> None:
        """Something time-driven changed (clock step, new timer, reliable publish): let an idle
        worker run housekeeping now."""
        self._executor.wake()

    def _on_remote_subscribe(self, prefix: bytes) -> None:
        with self._lock:
            latched = [p for p in self._publishers if p.qos.latched]
        for pub in latched:
            pub._resend_latched(prefix)

    def _on_ack(self, ack: CmdAck) -> None:
        if ack.src != self.src:
            return
        pub = self._ack_targets.get(ack.topic)
        if pub is not None:
            pub._ack(ack.seq)

    def _send_ack(self, topic: str, header: Header) -> None:
        pub = self._ack_pubs.get(topic)
        if pub is not None:
            pub.publish(
                CmdAck(
                    stamp_ns=self.clock.now_ns(),
                    topic=topic,
                    src=header.src,
                    seq=header.seq,
                    node=self.name,
                )
            )

    def _periodic(self) -> float:
        """The node's own duties in the executor role (``/diagnostics``, ``COMMAND``
        retransmissions); return wall s until they are due again (at most 1)."""
        wait = 1.0
        if self.diagnostics_period_s > 0:
            now = time.monotonic()
            if now >= self._next_diag:
                self._publish_diagnostics()
                self._next_diag = now + self.diagnostics_period_s
            wait = min(wait, max(0.0, self._next_diag - time.monotonic()))
        with self._lock:
            reliable = [p for p in self._publishers if p.qos.reliable]
        now = time.monotonic()
        for pub in reliable:
            due = pub._retransmit(now)
            if due is not None:
                wait = min(wait, max(0.0, due - now))
        return wait

    def _publish_diagnostics(self) -> None:
        if self._diag_pub is not None:
            self._diag_pub.publish(self._diagnostics())

    def __repr__(self) -> str:
        return f"Node({self.name!r}, bus={self.bus!r})"
