"""The executor of a :class:`hil_bridge.bus.node.Node`: its two worker threads, the lanes its
deliveries queue in, and reception (decode, deduplicate, acknowledge).

The workers run in a leader/follower pattern:

- at any time one worker is the *leader*: it alone receives, decodes, deduplicates and
  acknowledges ``COMMAND`` messages, in arrival order;
- at most one worker holds the *executor* role: it runs subscription callbacks, timers (on the
  node's :class:`SimClock`) and the node's periodic duties (``COMMAND`` retransmissions and the
  periodic ``/diagnostics``), one at a time (like rclpy's single-threaded executor).

A leader keeps leading from one message to the next. One that receives a message while the
executor role is free and nothing is queued runs its callbacks itself, in subscription order
(no thread hand-off on the latency path). At a low message rate it first hands leadership to the
other worker, so that a slow callback costs drops on its own queue, never stalled reception.
At :data:`FAST_RATE_HZ` messages a second or more, waking the other worker for every message
would cost more than the callbacks (a context switch or two each, on the very cores the loop is
short of): the leader then runs the callbacks *keeping* leadership, and the other worker, which
wakes every :data:`WATCH_S` while the rate lasts, takes reception over if a callback holds it
longer than that. Reception then stalls for at most about ``WATCH_S`` behind a slow callback.
Otherwise the message goes to its subscriptions' keep-last queues (depth from the QoS profile;
overflow dropped and counted; reliable subscriptions never drop an acknowledged message).

A frame that does not decode (unknown type, newer version, wrong type for the topic, corrupt)
is dropped and counted as ``decode_errors``: bad input, not a fault. An exception in a
subscription callback (``callback_errors`` of its topic), in a timer callback
(``callback_errors`` of ``/timers``) or in reception is counted and reported to the node's
:class:`~hil_bridge.bus.faults.Faults` (so the node's ``failure()`` names it and a launch run
exits non-zero); none ever ends a worker.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from hil_bridge.bus.clock import SimClock
from hil_bridge.bus.codec import Envelope, Header, decode_header, decode_payload
from hil_bridge.bus.endpoints import Lane, Subscription, Timer
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import Message
from hil_bridge.bus.transport import Transport
from hil_bridge.errors import CodecError

__all__ = ["DECODE_LOG_PERIOD_S", "FAST_RATE_HZ", "WATCH_S", "Executor"]

log = logging.getLogger(__name__)

_RX_SLICE_S = 0.02
_MIN_RESET_PERIOD_S = 0.05
#: messages a second from which the leader runs callbacks inline without handing leadership on
FAST_RATE_HZ = 200.0
#: the longest an inline callback holds reception at that rate before the other worker takes it
WATCH_S = 0.005
#: how often the leader measures the message rate (s)
_RATE_WINDOW_S = 0.25
#: undecodable messages are logged once per topic per this many seconds (with their count)
DECODE_LOG_PERIOD_S = 10.0


def _callable_name(fn: Callable[..., Any]) -> str:
    return str(getattr(fn, "__qualname__", None) or getattr(fn, "__name__", None) or fn)


class Executor:
    """The two workers of the node ``name`` (module docstring).

    ``send_ack(topic, header)`` acknowledges a reliable message; ``periodic()`` runs the node's
    own duties in the executor role and returns wall seconds until they are due again;
    ``counters(topic)`` is the node's counter dict of a topic. ``own``: the header bytes that
    mark this process's composed publishers (:mod:`hil_bridge.bus.intra`): frames holding them
    came back over the transport after they were handed over in-process, and are skipped
    (``loopback``) before they are decoded.
    """

    def __init__(
        self,
        name: str,
        transport: Transport,
        clock: SimClock,
        faults: Faults,
        *,
        send_ack: Callable[[str, Header], None],
        periodic: Callable[[], float],
        counters: Callable[[str], dict[str, int]],
        own: bytes | None = None,
    ) -> None:
        self.name = name
        self.transport = transport
        self.clock = clock
        self.faults = faults
        self._send_ack = send_ack
        self._periodic = periodic
        self._counters = counters
        self._own = own
        #: frames of this process's composed publishers skipped on reception
        self.loopback = 0
        self._lock = threading.Lock()
        self._cond = threading.Condition()
        #: frame prefix (topic + NUL) -> its subscriptions (replaced, never mutated in place)
        self._subs: dict[bytes, list[Subscription[Any]]] = {}
        self._timers: list[Timer] = []
        #: subscriptions with queued messages, served round-robin; priority ones first
        self._ready: deque[Lane] = deque()
        self._ready_hi: deque[Lane] = deque()
        self._lanes: dict[str, Lane] = {}
        self._decode_log: dict[str, list[Any]] = {}
        self._next_reset: dict[bytes, float] = {}
        self._leading = False
        self._busy = False
        #: fast mode (module docstring): the idle worker watches the leader every WATCH_S
        self._watch = False
        #: the leader runs a callback inline, keeping leadership, since _inline_t0
        self._inline_lead = False
        self._inline_t0 = 0.0
        #: bumped when the watching worker takes leadership from an inline callback
        self._lead_gen = 0
        #: the message rate's window (kept by whichever worker leads)
        self._window_t0 = time.monotonic()
        self._window_n = 0
        self._next_housekeeping = 0.0
        self._next_service = 0.0
        self.stopping = False
        self._threads: list[threading.Thread] = []

    # -- what the node registers -------------------------------------------------------------
    def lane(self, name: str) -> Lane:
        """The lane shared by the subscriptions made with ``lane=name``."""
        with self._lock:
            return self._lanes.setdefault(name, Lane())

    def add_subscription(self, frame: bytes, sub: Subscription[Any]) -> None:
        with self._lock:
            self._subs[frame] = [*self._subs.get(frame, []), sub]

    def add_timer(self, timer: Timer) -> None:
        with self._lock:
            self._timers.append(timer)
        self.wake()

    def subscriptions(self) -> list[Subscription[Any]]:
        with self._lock:
            return [sub for subs in self._subs.values() for sub in subs]

    @property
    def has_timers(self) -> bool:
        return bool(self._timers)

    def timers(self) -> list[Timer]:
        with self._lock:
            return list(self._timers)

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        """Start the two workers (once)."""
        self._threads = [
            threading.Thread(target=self._worker, name=f"{self.name}-w{k}", daemon=True)
            for k in range(2)
        ]
        for thread in self._threads:
            thread.start()

    def stop(self) -> None:
        """Stop the workers and join them (but never the calling thread)."""
        self.stopping = True
        threads, self._threads = self._threads, []
        self.transport.wakeup()
        self.wake()
        for thread in threads:
            if thread is not threading.current_thread():
                thread.join()

    def wake(self) -> None:
        """Something time-driven changed (clock step, new timer, reliable publish): let an idle
        worker run housekeeping now."""
        with self._cond:
            self._next_housekeeping = 0.0
            self._cond.notify_all()

    # -- the workers -------------------------------------------------------------------------
    def _worker(self) -> None:
        """One of the two workers (leader/follower): at any time at most one of them receives
        (the leader) and at most one runs user code (the executor role)."""
        cond = self._cond
        while True:
            job: tuple[Subscription[Any], Envelope] | None = None
            with cond:
                while True:
                    if self.stopping:
                        return
                    if not self._busy and (self._ready_hi or self._ready):
                        job = self._pop_ready()
                        self._busy = True
                        mode = "callback"
                        break
                    if not self._leading:
                        self._leading = True
                        mode = "lead"
                        break
                    now = time.monotonic()
                    if self._inline_lead and now - self._inline_t0 >= WATCH_S:
                        # the leader is held up in a callback it runs inline: take reception
                        # over (the callback keeps the executor role until it returns)
                        self._inline_lead = False
                        self._lead_gen += 1
                        mode = "lead"
                        break
                    wait = self._next_housekeeping - now
                    if not self._busy and wait <= 0:
                        self._busy = True
                        mode = "housekeeping"
                        break
                    timeout = wait if wait > 0 else None
                    if self._watch:
                        timeout = WATCH_S if timeout is None else min(timeout, WATCH_S)
                    cond.wait(timeout)
            if mode == "lead":
                inline = self._lead()
                if inline is not None:
                    for delivery in inline:
                        self._run_callback(*delivery)
                    self._release()
            elif mode == "callback" and job is not None:
                self._run_callback(*job)
                self._release()
            else:
                wait = self._housekeeping()
                with cond:
                    self._next_housekeeping = time.monotonic() + wait
                self._release()

    def _pop_ready(self) -> tuple[Subscription[Any], Envelope]:
        """Next queued delivery (``_cond`` held): priority lanes first, one delivery per lane in
        turn (so a flooded topic cannot starve another), in arrival order within a lane."""
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
        """Queue a delivery (``_cond`` held); beyond the subscription's bound its oldest queued
        delivery is dropped."""
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

    def _release(self) -> None:
        with self._cond:
            self._busy = False
            self._cond.notify_all()

    # -- reception ---------------------------------------------------------------------------
    def _lead(self) -> list[tuple[Subscription[Any], Envelope]] | None:
        """Receive as the leader: take messages off the transport (decode, deduplicate,
        acknowledge, queue) until the node stops, or until a message's deliveries (one per
        subscription of its topic) are to run inline with leadership handed on (returned: the
        executor role is then reserved for them), or until
        the other worker took leadership over from a callback run inline here (module
        docstring). Undecodable messages are dropped and counted here, before they queue."""
        transport = self.transport
        cond = self._cond
        gen = self._lead_gen
        own = self._own
        try:
            while not self.stopping:
                now = time.monotonic()
                if now >= self._next_service:
                    transport.service(0.0)
                    self._next_service = now + _RX_SLICE_S
                if now - self._window_t0 >= _RATE_WINDOW_S:
                    self._set_watch(self._window_n / (now - self._window_t0) >= FAST_RATE_HZ)
                    self._window_t0, self._window_n = now, 0
                frames = transport.recv(timeout=_RX_SLICE_S)
                if frames is None:
                    continue
                if own is not None and len(frames) == 3 and own in frames[1]:
                    self.loopback += 1  # handed over in-process already
                    continue
                self._window_n += 1
                subs = self._subs.get(frames[0])
                deliveries = self._process(subs, frames) if subs else []
                if not deliveries:
                    continue
                inline: list[tuple[Subscription[Any], Envelope]] | None = None
                with cond:
                    if not self._busy and not self._ready_hi and not self._ready:
                        self._busy = True
                        inline = deliveries
                        if not self._watch:
                            self._leading = False  # the other worker leads meanwhile
                            cond.notify_all()
                            return inline
                        self._inline_lead, self._inline_t0 = True, time.monotonic()
                    else:
                        for sub, envelope in deliveries:
                            self._enqueue(sub, envelope)
                        cond.notify_all()
                if inline is not None:
                    for delivery in inline:
                        self._run_callback(*delivery)
                    with cond:
                        self._busy = False
                        if self._ready_hi or self._ready:
                            cond.notify_all()
                        if gen != self._lead_gen:  # the other worker leads now
                            return None
                        self._inline_lead = False
        except Exception as exc:  # never let one message end reception; but say so
            self.faults.report("receiving", exc)
        with cond:
            if gen == self._lead_gen:
                self._inline_lead = False
                self._leading = False
            cond.notify_all()
        return None

    def _set_watch(self, fast: bool) -> None:
        """Enter or leave fast mode; entering wakes the other worker to watch."""
        with self._cond:
            if fast != self._watch:
                self._watch = fast
                if fast:
                    self._cond.notify_all()

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

    # -- composition -------------------------------------------------------------------------
    def deliver_local(self, sub: Subscription[Any], header: Header, msg: Message,
                      payload: bytes) -> None:
        """A message handed over in-process (:mod:`hil_bridge.bus.intra`), with the QoS of
        ``sub`` (``max_age_s``, acknowledgement, per-publisher ``seq`` accounting, keep-last
        depth): it queues as a received message does, or, for a subscription made
        ``inline=True``, its callback runs here on the publishing thread when the executor role
        is free, nothing is queued and the workers run (no thread hand-off)."""
        if self.stopping:
            return
        counters = sub._counters
        if sub.max_age_ns is not None and self.clock.now_ns() - header.stamp_ns > sub.max_age_ns:
            counters["stale"] += 1
            return
        if sub.qos.reliable:
            self._send_ack(sub.topic, header)
        if sub._is_duplicate(header):
            counters["duplicates"] += 1
            return
        counters["received"] += 1
        counters["local"] += 1
        envelope = Envelope(sub.topic, header, msg, payload)
        cond = self._cond
        with cond:
            inline = sub.inline and not self._busy and not self._ready_hi and not self._ready \
                and bool(self._threads)
            if inline:
                self._busy = True
            else:
                self._enqueue(sub, envelope)
                cond.notify_all()
        if inline:
            self._run_callback(sub, envelope)
            with cond:
                self._busy = False
                if (self._ready_hi or self._ready
                        or time.monotonic() >= self._next_housekeeping):
                    cond.notify_all()

    # -- the executor role -------------------------------------------------------------------
    def _run_callback(self, sub: Subscription[Any], envelope: Envelope) -> None:
        try:
            sub.callback(envelope if sub.envelope else envelope.msg)
        except Exception as exc:
            sub._counters["callback_errors"] += 1
            self.faults.report(f"callback {sub.topic}", exc)

    def _housekeeping(self) -> float:
        """Fire due timers and the node's periodic duties; return wall s until the next."""
        wait = self._periodic()
        with self._lock:
            timers = [t for t in self._timers if not t.cancelled]
            self._timers = timers
        now_ns = self.clock.now_ns()
        for timer in timers:
            if now_ns >= timer.next_ns:
                missed = (now_ns - timer.next_ns) // timer.period_ns
                timer.overruns += missed
                timer.next_ns += (missed + 1) * timer.period_ns
                timer.fired += 1
                try:
                    timer.callback()
                except Exception as exc:
                    self._counters("/timers")["callback_errors"] += 1
                    self.faults.report(f"timer {_callable_name(timer.callback)}", exc)
                now_ns = self.clock.now_ns()
            until = self.clock.wall_seconds_until(timer.next_ns)
            if until is not None:
                wait = min(wait, until)
        return wait
