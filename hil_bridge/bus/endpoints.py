"""Endpoints of a :class:`hil_bridge.bus.node.Node`: publishers, subscriptions (and the lanes
their deliveries queue in) and timers. They hold their own state (``seq``, pending
acknowledgements, per-publisher sequence accounting, queued deliveries); the node's workers
drive them (:mod:`hil_bridge.bus.executor`).

An endpoint knows its node only as an :class:`EndpointHost` (what it needs of it), so this
module imports neither the node nor the executor: both import it.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

from hil_bridge.bus.clock import SimClock
from hil_bridge.bus.codec import Envelope, Header, encode_payload, pack_header
from hil_bridge.bus.messages import Message
from hil_bridge.bus.qos import QoSProfile
from hil_bridge.bus.seq import SeqTracker, Verdict
from hil_bridge.bus.transport import Transport

if TYPE_CHECKING:
    from hil_bridge.bus.intra import IntraBus

__all__ = ["EndpointHost", "Lane", "Publisher", "Subscription", "Timer"]

M = TypeVar("M", bound=Message)

_SEEN_WINDOW = 1024
_RELIABLE_QUEUE_MAX = 4096


class EndpointHost(Protocol):
    """What an endpoint needs of its node (:class:`hil_bridge.bus.node.Node`): its ``src``
    (publisher id in headers), sim ``clock``, ``transport``, the counters of a topic and a way
    to wake its executor (a reliable publish or a cancelled timer changes what is due), and
    the composed bus its messages are also handed over on in this process
    (:mod:`hil_bridge.bus.intra`; None: not composed)."""

    src: str
    clock: SimClock
    transport: Transport
    intra: IntraBus | None

    def _topic(self, topic: str) -> dict[str, int]: ...

    def _wake_exec(self) -> None: ...


class Publisher(Generic[M]):
    """Made by :meth:`Node.create_publisher`. ``publish(msg)`` returns the message's ``seq``."""

    def __init__(
        self, node: EndpointHost, msg_type: type[M], topic: str, qos: QoSProfile,
        frame_id: str,
    ) -> None:
        self.node = node
        self.msg_type = msg_type
        self.topic = topic
        self.qos = qos
        self.frame_id = frame_id
        self.topic_frame = topic.encode() + b"\0"
        self._lock = threading.Lock()
        self._seq = 0
        self._last: list[bytes] | None = None
        self._last_local: tuple[Header, M, bytes] | None = None
        self._acked = threading.Condition(self._lock)
        #: seq -> [frames, first_sent_mono, next_retry_mono]
        self._pending: dict[int, list[Any]] = {}
        self._failed: deque[int] = deque(maxlen=_SEEN_WINDOW)
        self._counters = node._topic(topic)

    def publish(self, msg: M) -> int:
        """Send ``msg`` (its ``stamp_ns`` goes in the header); return its ``seq``. On a
        composed bus it is then handed to this process's subscriptions of the topic
        (:mod:`hil_bridge.bus.intra`)."""
        if type(msg) is not self.msg_type:
            raise TypeError(
                f"publisher of {self.topic!r} sends {self.msg_type.__name__}, "
                f"got {type(msg).__name__}"
            )
        intra = self.node.intra
        with self._lock:
            seq = self._seq
            stamp = int(msg.stamp_ns)  # type: ignore[attr-defined]
            header = Header(msg.TYPE, msg.VERSION, seq, stamp, time.monotonic_ns(),
                            self.frame_id, self.node.src)
            payload = encode_payload(msg)
            frames = [self.topic_frame, pack_header(header), payload]
            self.node.transport.publish(frames)
            self._seq = seq + 1
            self._counters["sent"] += 1
            if self.qos.latched:
                self._last = frames
                if intra is not None:
                    self._last_local = (header, msg, payload)
            if self.qos.reliable:
                now = time.monotonic()
                self._pending[seq] = [frames, now, now + self.qos.retry_period_s, header, msg]
        if self.qos.reliable:
            self.node._wake_exec()
        if intra is not None:
            for deliver, sub in intra.route(self.topic):
                deliver(sub, header, msg, payload)
        return seq

    def last_local(self) -> tuple[Header, M, bytes] | None:
        """A latched publisher's last message on a composed bus (header, message, payload)."""
        with self._lock:
            return self._last_local

    def wait_for_subscribers(self, timeout: float) -> bool:
        """True once a subscription to this topic is known to receive what is published next
        (the slow-joiner guard; no sleeping): in this process, on a composed bus, or over the
        transport. False after ``timeout`` seconds."""
        intra = self.node.intra
        if intra is not None and intra.route(self.topic):
            return True
        return self.node.transport.wait_for_subscriber(self.topic, timeout)

    def wait_for_ack(self, seq: int, timeout: float) -> bool:
        """``COMMAND`` publishers: True once ``seq`` is acknowledged, False on timeout or when
        it was given up (``ack_timeout_s``)."""
        if not self.qos.reliable:
            raise ValueError(f"publisher of {self.topic!r} is not reliable (qos {self.qos.name})")
        with self._lock:
            if seq >= self._seq:
                raise ValueError(f"seq {seq} was never published on {self.topic!r}")
            return self._acked.wait_for(lambda: seq not in self._pending, timeout) and (
                seq not in self._failed
            )

    @property
    def pending(self) -> int:
        """Reliable messages not yet acknowledged."""
        with self._lock:
            return len(self._pending)

    def _ack(self, seq: int) -> None:
        with self._lock:
            if self._pending.pop(seq, None) is not None:
                self._counters["acked"] += 1
                self._acked.notify_all()

    def _retransmit(self, now: float) -> float | None:
        """Re-send due messages; return the next due time (monotonic s) or None."""
        nxt: float | None = None
        again: list[tuple[Header, M, bytes]] = []
        with self._lock:
            for seq in list(self._pending):
                entry = self._pending[seq]
                frames, first, due = entry[:3]
                if now - first >= self.qos.ack_timeout_s:
                    del self._pending[seq]
                    self._failed.append(seq)
                    self._counters["ack_failed"] += 1
                    self._acked.notify_all()
                    continue
                if now >= due:
                    self.node.transport.publish(frames)
                    again.append((entry[3], entry[4], frames[2]))
                    self._counters["retransmits"] += 1
                    due = entry[2] = now + self.qos.retry_period_s
                nxt = due if nxt is None else min(nxt, due)
        intra = self.node.intra
        if intra is not None:  # the transport's copy of a re-send is skipped here as loopback
            for deliver, sub in intra.route(self.topic):
                for header, msg, payload in again:
                    deliver(sub, header, msg, payload)
        return nxt

    def _resend_latched(self, prefix: bytes) -> None:
        with self._lock:
            last = self._last
        if last is not None and self.topic_frame.startswith(prefix):
            self.node.transport.publish(last)
            self._counters["latched_resends"] = self._counters.get("latched_resends", 0) + 1


class Lane:
    """The deliveries queued for one or more subscriptions, in arrival order (a subscription's
    own lane, or the lane shared by subscriptions made with one ``lane`` name)."""

    __slots__ = ("priority", "queue", "scheduled")

    def __init__(self) -> None:
        self.queue: deque[tuple[Subscription[Any], Envelope]] = deque()
        self.priority = False
        self.scheduled = False


class Subscription(Generic[M]):
    """Made by :meth:`Node.create_subscription`; ``callback(msg)`` (or ``callback(envelope)``
    with ``envelope=True``) runs on a node worker, one callback at a time."""

    def __init__(
        self,
        node: EndpointHost,
        msg_type: type[M],
        topic: str,
        callback: Callable[[Any], None],
        qos: QoSProfile,
        envelope: bool,
        priority: bool = False,
        lane: Lane | None = None,
        inline: bool = False,
    ) -> None:
        self.node = node
        self.msg_type = msg_type
        self.topic = topic
        self.callback = callback
        self.qos = qos
        self.envelope = envelope
        self.priority = priority
        #: its callback is short and never blocks: on a composed bus it may run on the
        #: publishing thread (:meth:`~hil_bridge.bus.executor.Executor.deliver_local`)
        self.inline = inline
        self._lane = lane if lane is not None else Lane()
        self._lane.priority |= priority
        #: deliveries of this subscription waiting in its lane, at most ``limit``: keep-last
        #: ``depth`` (reliable: a large bound, never a drop in normal operation, but a flood
        #: cannot exhaust memory)
        self.queued = 0
        self.limit = max(qos.depth, _RELIABLE_QUEUE_MAX) if qos.reliable else qos.depth
        self.max_age_ns = None if qos.max_age_s is None else round(qos.max_age_s * 1e9)
        self._seq = SeqTracker(reliable=qos.reliable)
        self._counters = node._topic(topic)

    def _is_duplicate(self, header: Header) -> bool:
        """Account ``seq`` per publisher (:mod:`hil_bridge.bus.seq`): gaps count as drops, a jump
        or a step back starts a new epoch (counted, delivered); True only for a true re-send."""
        tracker = self._seq
        lost = tracker.lost
        verdict = tracker.observe(header.src, header.seq, header.stamp_ns, header.pub_ns)
        if verdict is Verdict.DUPLICATE:
            return True
        if verdict is Verdict.GAP:
            self._counters["dropped"] += tracker.lost - lost
        elif verdict is Verdict.EPOCH:
            self._counters["epochs"] += 1
        return False


class Timer:
    """Made by :meth:`Node.create_timer`; fires every ``period_ns`` of the node's sim clock."""

    def __init__(self, node: EndpointHost, period_s: float, callback: Callable[[], None]) -> None:
        if not period_s > 0:
            raise ValueError(f"timer period must be > 0 s, got {period_s!r}")
        self.node = node
        self.period_ns = max(1, round(period_s * 1e9))
        self.callback = callback
        self.next_ns = node.clock.now_ns() + self.period_ns
        self.fired = 0
        self.overruns = 0
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True
        self.node._wake_exec()
