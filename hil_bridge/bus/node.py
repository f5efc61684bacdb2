"""Nodes: rclpy-shaped publishers, subscriptions and timers over one bus transport.

A :class:`Node` opens its transport when constructed (so publishers and subscriptions made in
``__init__`` are live at once) and runs two worker threads after :meth:`Node.start`, in a
leader/follower pattern:

- at any time one worker is the *leader*: it alone receives, decodes, deduplicates and
  acknowledges ``COMMAND`` messages, in arrival order;
- at most one worker holds the *executor* role: it runs subscription callbacks, timers (on the
  node's :class:`SimClock`), ``COMMAND`` retransmissions and the periodic ``/diagnostics``, one at
  a time (like rclpy's single-threaded executor).

A leader that receives a message while the executor role is free and nothing is queued hands
leadership to the other worker and runs the callback itself (no thread hand-off on the latency
path). Otherwise the message goes to its subscription's keep-last queue (depth from the QoS
profile; overflow dropped and counted; reliable subscriptions never drop an acknowledged
message). Since a callback always leaves the other worker free to lead, a slow callback costs
drops on its own queue, never stalled reception.

A frame that does not decode (unknown type, newer version, wrong type for the topic, corrupt)
is dropped and counted as ``decode_errors``; an exception in a callback is logged and counted as
``callback_errors``; neither ever ends a thread. Publisher ``seq`` gaps are counted as
``dropped`` (the message was lost upstream, e.g. at a full queue).

:class:`Publisher`, :class:`Subscription` and :class:`Timer` live in :mod:`hil_bridge.bus.endpoints`
(importable from here too).

The *launchable* contract (``Cls(name, *, bus, **params)``, ``start()``, ``stop()``,
``stats()``) is met by :class:`Node` and by subclasses that add their own parameters.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from types import TracebackType
from typing import Any, TypeVar

from hil_bridge.bus.clock import SimClock, default_clock
from hil_bridge.bus.codec import Envelope, Header, decode_header, decode_payload, validate_topic
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.endpoints import Publisher, Subscription, Timer, _Lane
from hil_bridge.bus.messages import Clock, CmdAck, Diagnostics, Message
from hil_bridge.bus.qos import LATCHED, SENSOR, QoSProfile, qos_profile
from hil_bridge.bus.transport import Transport, open_transport
from hil_bridge.errors import CodecError

__all__ = ["Node", "Publisher", "Subscription", "Timer"]

log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)

_NODE_IDS = itertools.count()
_NAME_RE = re.compile(r"^[A-Za-z0-9_]+$")
_RX_SLICE_S = 0.02
#: a leader handles at most this many messages (or _RX_BATCH_S seconds) before handing on
_RX_BATCH = 256
_RX_BATCH_S = 0.005
_MIN_RESET_PERIOD_S = 0.05
#: undecodable messages are logged once per topic per this many seconds (with their count)
DECODE_LOG_PERIOD_S = 10.0


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
    }



class Node:
    """A bus participant: ``Node(name, *, bus=None, clock=None, diagnostics_period_s=1.0)``.

    ``bus`` defaults to the current domain's bus (:mod:`hil_bridge.bus.domain`).

    ``clock`` defaults to :func:`~hil_bridge.bus.clock.default_clock`. ``diagnostics_period_s``
    (wall seconds; 0 disables) sets how often ``/diagnostics`` carries :meth:`stats`.
    Use as a context manager or call :meth:`stop` (idempotent) to close threads and sockets.
    """

    def __init__(
        self,
        name: str,
        *,
        bus: str | None = None,
        clock: SimClock | None = None,
        diagnostics_period_s: float = 1.0,
    ) -> None:
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise ValueError(f"node name must be a non-empty [A-Za-z0-9_] string, got {name!r}")
        if diagnostics_period_s < 0:
            raise ValueError(f"diagnostics_period_s must be >= 0, got {diagnostics_period_s}")
        self.name = name
        self.bus = bus if bus is not None else current_domain().bus_url
        self.clock = clock if clock is not None else default_clock()
        self.src = f"{name}#{os.getpid():x}.{next(_NODE_IDS)}.{os.urandom(3).hex()}"
        self.diagnostics_period_s = diagnostics_period_s
        self._counters_by_topic: dict[str, dict[str, int]] = {}
        self._publishers: list[Publisher[Any]] = []
        self._subs: dict[bytes, list[Subscription[Any]]] = {}
        self._timers: list[Timer] = []
        self._ack_pubs: dict[str, Publisher[CmdAck]] = {}
        self._ack_targets: dict[str, Publisher[Any]] = {}
        self._lock = threading.RLock()
        self._exec_cond = threading.Condition()
        #: subscriptions with queued messages, served round-robin; priority ones first
        self._ready: deque[_Lane] = deque()
        self._ready_hi: deque[_Lane] = deque()
        self._lanes: dict[str, _Lane] = {}
        self._decode_log: dict[str, list[Any]] = {}
        self._next_reset: dict[bytes, float] = {}
        self._leading = False
        self._exec_busy = False
        self._next_housekeeping = 0.0
        self._next_service = 0.0
        self._next_diag = 0.0
        self._stopping = False
        self._stopped = False
        self._threads: list[threading.Thread] = []
        self._diag_pub: Publisher[Diagnostics] | None = None
        self.transport: Transport = open_transport(self.bus)
        self.transport.on_subscribe = self._on_remote_subscribe
        self.clock.add_listener(self._wake_exec)

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
    ) -> Publisher[M]:
        """A publisher of ``msg_type`` on ``topic`` with ``qos`` (SENSOR, COMMAND or LATCHED)."""
        self._check_type(msg_type)
        validate_topic(topic)
        profile = qos_profile(qos)
        pub = Publisher(self, msg_type, topic, profile, frame_id)
        with self._lock:
            self._publishers.append(pub)
            if profile.reliable:
                self._ack_targets[topic] = pub
        if profile.reliable:
            self._add_subscription(CmdAck, f"{topic}/ack", self._on_ack, SENSOR, False, True)
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
    ) -> Subscription[M]:
        """Call ``callback(msg)`` for each ``msg_type`` message on ``topic`` (``envelope=True``:
        ``callback(Envelope)`` with topic, header and raw payload). ``priority=True`` puts the
        subscription on the control path: its callbacks run before any other queued ones.

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
                    self._ack_pubs[topic] = self.create_publisher(CmdAck, f"{topic}/ack")
        return self._add_subscription(msg_type, topic, callback, profile, envelope, priority,
                                      lane)

    def _add_subscription(
        self,
        msg_type: type[M],
        topic: str,
        callback: Callable[[Any], None],
        qos: QoSProfile,
        envelope: bool,
        priority: bool = False,
        lane: str | None = None,
    ) -> Subscription[M]:
        with self._lock:
            shared = None if lane is None else self._lanes.setdefault(lane, _Lane())
        sub = Subscription(self, msg_type, topic, callback, qos, envelope, priority, shared)
        frame = topic.encode() + b"\0"
        with self._lock:
            self._subs[frame] = [*self._subs.get(frame, []), sub]
        self.transport.subscribe(frame, lane=None if lane is None else f"lane:{lane}")
        return sub

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> Timer:
        """Call ``callback()`` every ``period_s`` seconds of the node's sim clock."""
        timer = Timer(self, period_s, callback)
        with self._lock:
            self._timers.append(timer)
        self._wake_exec()
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
            if self._threads or self._stopped:
                if self._stopped:
                    raise RuntimeError(f"node {self.name!r} was stopped; make a new one")
                return self
            if self.diagnostics_period_s > 0 and self._diag_pub is None:
                self._diag_pub = self.create_publisher(Diagnostics, "/diagnostics")
            self._next_diag = time.monotonic() + self.diagnostics_period_s
            self._threads = [
                threading.Thread(target=self._worker, name=f"{self.name}-w{k}", daemon=True)
                for k in range(2)
            ]
            for thread in self._threads:
                thread.start()
        return self

    def stop(self) -> None:
        """Stop threads, join them and close the transport (idempotent)."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
            self._stopping = True
            threads, self._threads = self._threads, []
        self.transport.wakeup()
        self._wake_exec()
        for thread in threads:
            if thread is not threading.current_thread():
                thread.join()
        self.clock.remove_listener(self._wake_exec)
        self.transport.close()

    @property
    def running(self) -> bool:
        return bool(self._threads) and not self._stopping

    def __enter__(self) -> Node:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # -- counters ----------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """``{"node", "sent", "received", "dropped", "duplicates", "decode_errors",
        "callback_errors", "retransmits", "acked", "ack_failed", "timer_overruns",
        "topics": {topic: {...}}, "transport": {...}}``."""
        with self._lock:
            topics = {t: dict(c) for t, c in self._counters_by_topic.items()}
            overruns = sum(t.overruns for t in self._timers)
        totals: dict[str, Any] = {"node": self.name}
        for key in _topic_counters():
            totals[key] = sum(c.get(key, 0) for c in topics.values())
        totals["timer_overruns"] = overruns
        totals["topics"] = topics
        totals["transport"] = self.transport.stats()
        return totals

    def _diagnostics(self) -> Diagnostics:
        stats = self.stats()
        counters: dict[str, int | float] = {
            k: v for k, v in stats.items() if isinstance(v, (int, float))
        }
        for topic, c in stats["topics"].items():
            for key in ("sent", "received", "dropped", "epochs", "stale", "decode_errors"):
                if c[key]:
                    counters[f"{key}:{topic}"] = c[key]
        return Diagnostics(stamp_ns=self.clock.now_ns(), node=self.name, counters=counters)

    # -- internals ---------------------------------------------------------------------------
    def _wake_exec(self) -> None:
        """Something time-driven changed (clock step, new timer, reliable publish): let an idle
        worker run housekeeping now."""
        with self._exec_cond:
            self._next_housekeeping = 0.0
            self._exec_cond.notify_all()

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

    def _decode_error(self, sub: Subscription[Any], exc: Exception) -> None:
        """Count an undecodable message on ``sub``'s topic; log once per topic per
        :data:`DECODE_LOG_PERIOD_S` with the count since the last line (never per message)."""
        sub._counters["decode_errors"] += 1
        entry = self._decode_log.get(sub.topic)
        if entry is None:
            self._decode_log[sub.topic] = [time.monotonic(), 0]
            log.warning("%s: dropped an undecodable message on %r (%s); more are counted and "
                        "summarised every %.0f s", self.name, sub.topic, exc,
                        DECODE_LOG_PERIOD_S)
            return
        entry[1] += 1
        if entry[1] & 63:  # a flood costs a clock read per 64 messages, not per message
            return
        now = time.monotonic()
        if now - entry[0] >= DECODE_LOG_PERIOD_S:
            log.warning("%s: dropped %d undecodable message(s) on %r in the last %.0f s "
                        "(last: %s)", self.name, entry[1], sub.topic, now - entry[0], exc)
            entry[0], entry[1] = now, 0

    def _worker(self) -> None:
        """One of the node's two workers (leader/follower): at any time at most one of them
        receives (the leader) and at most one runs user code (the executor role)."""
        cond = self._exec_cond
        while True:
            job: tuple[Subscription[Any], Envelope] | None = None
            with cond:
                while True:
                    if self._stopping:
                        return
                    if not self._exec_busy and (self._ready_hi or self._ready):
                        job = self._pop_ready()
                        self._exec_busy = True
                        mode = "callback"
                        break
                    if not self._leading:
                        self._leading = True
                        mode = "lead"
                        break
                    wait = self._next_housekeeping - time.monotonic()
                    if not self._exec_busy and wait <= 0:
                        self._exec_busy = True
                        mode = "housekeeping"
                        break
                    cond.wait(wait if wait > 0 else None)
            if mode == "lead":
                inline = self._lead()
                if inline is not None:
                    self._run_callback(*inline)
                    self._release_exec()
            elif mode == "callback" and job is not None:
                self._run_callback(*job)
                self._release_exec()
            else:
                wait = self._housekeeping()
                with cond:
                    self._next_housekeeping = time.monotonic() + wait
                self._release_exec()

    def _pop_ready(self) -> tuple[Subscription[Any], Envelope]:
        """Next queued delivery (``_exec_cond`` held): priority lanes first, one delivery per
        lane in turn (so a flooded topic cannot starve another), in arrival order within a
        lane."""
        ready = self._ready_hi if self._ready_hi else self._ready
        lane = ready.popleft()
        sub, envelope = lane.queue.popleft()
        sub.queued -= 1
        if lane.queue:
            ready.append(lane)
        else:
            lane.scheduled = False
        return sub, envelope

    def _enqueue(self, sub: Subscription[Any], envelope: Envelope) -> None:
        """Queue a delivery (``_exec_cond`` held); beyond the subscription's bound its oldest
        queued delivery is dropped."""
        lane = sub._lane
        if sub.queued >= sub.limit:
            for i, (owner, _) in enumerate(lane.queue):
                if owner is sub:
                    del lane.queue[i]
                    break
            sub.queued -= 1
            sub._counters["dropped"] += 1
        lane.queue.append((sub, envelope))
        sub.queued += 1
        if not lane.scheduled:
            lane.scheduled = True
            (self._ready_hi if lane.priority else self._ready).append(lane)

    def _release_exec(self) -> None:
        with self._exec_cond:
            self._exec_busy = False
            self._exec_cond.notify_all()

    def _lead(self) -> tuple[Subscription[Any], Envelope] | None:
        """Receive as the leader: take messages off the transport (decode, deduplicate,
        acknowledge, queue), up to ``_RX_BATCH`` of them or ``_RX_BATCH_S`` seconds while they
        keep coming, then hand leadership on. Undecodable messages are dropped and counted here,
        before they queue. Returns a delivery to run inline (the executor role is then reserved
        for it): the first one that finds the executor idle and nothing queued."""
        inline: tuple[Subscription[Any], Envelope] | None = None
        transport = self.transport
        cond = self._exec_cond
        try:
            now = time.monotonic()
            if now >= self._next_service:
                transport.service(0.0)
                self._next_service = now + _RX_SLICE_S
            frames = transport.recv(timeout=_RX_SLICE_S)
            handled = 0
            until = time.monotonic() + _RX_BATCH_S
            while frames is not None and not self._stopping:
                subs = self._subs.get(frames[0])
                deliveries = self._process(subs, frames) if subs else []
                if deliveries:
                    with cond:
                        if (len(deliveries) == 1 and not self._exec_busy and not self._ready_hi
                                and not self._ready):
                            self._exec_busy = True
                            inline = deliveries[0]
                        else:
                            for sub, envelope in deliveries:
                                self._enqueue(sub, envelope)
                            cond.notify_all()
                    if inline is not None:
                        break
                handled += 1
                if handled >= _RX_BATCH or (handled & 15 == 0 and time.monotonic() >= until):
                    break
                frames = transport.recv(timeout=0.0)
        except Exception:  # never let one message end reception
            log.exception("%s: receiving failed", self.name)
        with cond:
            self._leading = False
            cond.notify_all()
        return inline

    def _process(
        self, subs: list[Subscription[Any]], frames: list[bytes]
    ) -> list[tuple[Subscription[Any], Envelope]]:
        """Decode, deduplicate, acknowledge; return what to deliver (in arrival order)."""
        if len(frames) != 3:  # a foreign ZeroMQ publisher on the proxy
            self._decode_error(subs[0], CodecError(f"{len(frames)} frames, expected 3"))
            return []
        try:
            header = decode_header(frames[1])
        except CodecError as exc:
            self._decode_error(subs[0], exc)
            return []
        decoded: Message | None = None
        topic = subs[0].topic
        payload = frames[2]
        out: list[tuple[Subscription[Any], Envelope]] = []
        for sub in subs:
            counters = sub._counters
            if header.type != sub.msg_type.TYPE:
                self._decode_error(
                    sub, CodecError(f"type {header.type!r} on a {sub.msg_type.TYPE} subscription")
                )
                continue
            if sub.max_age_ns is not None and (
                self.clock.now_ns() - header.stamp_ns > sub.max_age_ns
            ):
                counters["stale"] += 1
                self._reset_lane(sub, frames[0])
                continue
            if decoded is None:
                try:
                    decoded = decode_payload(header.type, header.v, payload)
                except CodecError as exc:
                    self._decode_error(sub, exc)
                    return []
            if sub.qos.reliable:
                self._send_ack(topic, header)
            if sub._is_duplicate(header):
                counters["duplicates"] += 1
                continue
            counters["received"] += 1
            out.append((sub, Envelope(topic, header, decoded, payload)))
        return out

    def _reset_lane(self, sub: Subscription[Any], frame: bytes) -> None:
        """A message too old for ``sub`` (``max_age_s``): what is queued behind it in the
        transport is older still, so drop that backlog (at most once per ``max_age_s``)."""
        now = time.monotonic()
        if now < self._next_reset.get(frame, 0.0):
            return
        age_s = (sub.max_age_ns or 0) / 1e9
        self._next_reset[frame] = now + max(_MIN_RESET_PERIOD_S, age_s)
        self.transport.reset(frame)
        sub._counters["queue_resets"] = sub._counters.get("queue_resets", 0) + 1

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

    def _run_callback(self, sub: Subscription[Any], envelope: Envelope) -> None:
        try:
            sub.callback(envelope if sub.envelope else envelope.msg)
        except Exception:
            sub._counters["callback_errors"] += 1
            log.exception("%s: callback on %r raised", self.name, sub.topic)

    def _housekeeping(self) -> float:
        """Fire due timers, retransmissions and diagnostics; return wall s until the next."""
        wait = 1.0
        if self.diagnostics_period_s > 0:
            now = time.monotonic()
            if now >= self._next_diag:
                self._publish_diagnostics()
                self._next_diag = now + self.diagnostics_period_s
            wait = min(wait, max(0.0, self._next_diag - time.monotonic()))
        with self._lock:
            timers = [t for t in self._timers if not t.cancelled]
            self._timers = timers
            reliable = [p for p in self._publishers if p.qos.reliable]
        now_ns = self.clock.now_ns()
        for timer in timers:
            if now_ns >= timer.next_ns:
                missed = (now_ns - timer.next_ns) // timer.period_ns
                timer.overruns += missed
                timer.next_ns += (missed + 1) * timer.period_ns
                timer.fired += 1
                try:
                    timer.callback()
                except Exception:
                    self._topic("/timers")["callback_errors"] += 1
                    log.exception("%s: timer callback raised", self.name)
                now_ns = self.clock.now_ns()
            until = self.clock.wall_seconds_until(timer.next_ns)
            if until is not None:
                wait = min(wait, until)
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
