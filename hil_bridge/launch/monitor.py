"""The launch run summary's bus-level observer (:class:`BusMonitor`)."""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

from hil_bridge.bus.faults import Faults
from hil_bridge.bus.stats import TopicStats

__all__ = ["BusMonitor"]


class BusMonitor:
    """Launchable bus-level observer behind the run summary (one raw subscription to all).

    Counts messages per topic and sequence gaps per (publisher, topic) as drops with
    :class:`hil_bridge.tools.topic.TopicStats` (a retransmission is a duplicate, not a gap);
    the state path latency (receive time minus the header's ``pub_ns``, both
    ``time.monotonic_ns``), the gaps between consecutive publishes of a state topic (``pub_ns``
    to ``pub_ns`` of one publisher's consecutive ``seq``: the publisher's pace, whatever the
    monitor's own delays) and ping -> echo latency (echo arrival minus ping arrival, matched
    by sonar and ``ping_seq``).
    Undecodable messages are counted in ``bad``, never raised.

    An observer, not the control path: it may share the process (and its GIL) with the nodes,
    so it uses at most :attr:`CPU_SHARE` of a core, and :attr:`FLOOD_CPU_SHARE` while
    undecodable messages outnumber good ones (more than :attr:`FLOOD_BAD_PER_S`): a flood of
    garbage must not take the adapters' time. Beyond its share it sleeps, its socket drops what
    it cannot take, and ``throttled_s`` says for how long its counts are partial. Its thread
    runs at a lower CPU priority (nice :attr:`NICE`), so that on a machine short of cores the
    nodes come first: it receives every message of the run, every state and echo included, and
    at the nodes' priority it took the cores from the server's tick loop when they were short.
    What it measures on receipt (``state_latency_ms``) then includes its own wait for a core;
    ``state_gap_ms`` comes from the publishers' clocks. In a launch of real-time nodes
    (``realtime`` > 0, :mod:`hil_bridge.priority`) it runs instead under ``SCHED_FIFO`` at that
    priority (the launch gives it 1, the lowest: after every real-time node, before every normal
    thread), so that it measures the bus, not its wait behind the real-time nodes.
    """

    CPU_SHARE = 0.5
    NICE = 5
    FLOOD_CPU_SHARE = 0.05
    FLOOD_BAD_PER_S = 1000

    def __init__(self, name: str, *, bus: str, realtime: int = 0) -> None:
        self.name = name
        self.bus = bus
        self.realtime = realtime
        self._transport: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._topics: dict[str, TopicStats] = {}
        self._bad = 0
        self._state_ms: deque[float] = deque(maxlen=50000)
        self._state_gap_ms: deque[float] = deque(maxlen=50000)
        #: per state topic: the last state's publisher, seq and pub_ns
        self._last_state: dict[str, tuple[str, int, int]] = {}
        self._ping_echo_ms: deque[float] = deque(maxlen=10000)
        self._pings: dict[tuple[str, int], int] = {}
        self._throttled_s = 0.0
        #: its receive thread's end by an exception (a failure of the run)
        self.faults = Faults(name)

    def start(self) -> None:
        from hil_bridge.bus.transport import open_transport
        from hil_bridge.priority import realtime_io

        if self.realtime:  # its I/O thread, if this opens the process's first endpoint
            realtime_io(self.realtime)
        self._transport = open_transport(self.bus)
        self._transport.subscribe(b"")
        self._thread = threading.Thread(target=self.faults.guarded("receive loop", self._loop),
                                        name=f"{self.name}-rx", daemon=True)
        self._thread.start()

    def failure(self, *, final: bool = False) -> str | None:
        """Why the monitor failed (its receive thread died), or None."""
        return self.faults.failure(final=final)

    def stop(self) -> None:
        self._stop.set()
        if self._transport is not None:
            self._transport.wakeup()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._transport is not None:
            self._transport.close()

    def _loop(self) -> None:
        from hil_bridge.bus.codec import decode_payload, decode_topic_header
        from hil_bridge.errors import CodecError, HilError
        from hil_bridge.priority import lower_priority, realtime

        if self.realtime:
            realtime(self.realtime)
        else:
            lower_priority(self.NICE, thread_only=True)

        window_wall, window_cpu, window_bad, n = time.monotonic(), time.thread_time(), 0, 0
        while not self._stop.is_set():
            try:
                frames = self._transport.recv(timeout=0.1)
            except HilError:
                return
            if frames is None:
                continue
            n += 1
            if n % 128 == 0:  # keep to its share of a core, measured per window of ~1 s
                wall, cpu = time.monotonic() - window_wall, time.thread_time() - window_cpu
                bad = self._bad - window_bad
                flood = bad > max(self.FLOOD_BAD_PER_S * wall, n - bad)
                behind = cpu / (self.FLOOD_CPU_SHARE if flood else self.CPU_SHARE) - wall
                if behind > 0.001:
                    pause = min(behind, 0.5)
                    self._stop.wait(pause)
                    with self._lock:
                        self._throttled_s += pause
                if wall > 1.0:
                    window_wall, window_cpu, window_bad = (
                        time.monotonic(), time.thread_time(), self._bad)
                    n = 0
            now = time.monotonic_ns()
            try:
                topic, header = decode_topic_header(frames)
                ping_key: tuple[str, int] | None = None
                is_state = topic.startswith("/glider/") and topic.endswith("/state")
                if is_state or (topic.startswith("/sonar/")
                                and topic.endswith(("/ping", "/echo"))):
                    # decoded in full: a forged header must not pass for a state or a ping
                    msg = decode_payload(header.type, header.v, frames[2])
                    if is_state and header.type != "echoloop/GliderState":
                        raise CodecError(f"{header.type} on a state topic")
                    ping_key = (None if is_state else
                                (topic.rsplit("/", 1)[0], int(getattr(msg, "ping_seq", -1))))
            except (HilError, ValueError):
                with self._lock:
                    self._bad += 1
                continue
            with self._lock:
                ts = self._topics.get(topic)
                if ts is None:
                    ts = self._topics[topic] = TopicStats(topic)
                ts.add(header, sum(len(f) for f in frames), now)
                if is_state:
                    self._state_ms.append((now - header.pub_ns) / 1e6)
                    last = self._last_state.get(topic)
                    if last is not None and last[:2] == (header.src, header.seq - 1):
                        self._state_gap_ms.append((header.pub_ns - last[2]) / 1e6)
                    self._last_state[topic] = (header.src, header.seq, header.pub_ns)
                elif ping_key is not None and topic.endswith("/ping"):
                    self._pings[ping_key] = now
                    if len(self._pings) > 4096:
                        self._pings.pop(next(iter(self._pings)))
                elif ping_key is not None:
                    t_ping = self._pings.pop(ping_key, None)
                    if t_ping is not None:
                        self._ping_echo_ms.append((now - t_ping) / 1e6)

    def stats(self) -> dict[str, Any]:
        from hil_bridge.bus.stats import percentiles

        with self._lock:
            topics = {}
            for topic, ts in self._topics.items():
                span = ((ts.last_recv_ns or 0) - (ts.first_recv_ns or 0)) / 1e9
                topics[topic] = {"count": ts.count,
                                 "rate_hz": (ts.count - 1) / span if span > 0 else 0.0}
            return {
                "topics": topics,
                "messages": sum(ts.count for ts in self._topics.values()),
                "duplicates": sum(ts.duplicates for ts in self._topics.values()),
                "seq_gaps": sum(ts.lost for ts in self._topics.values()),
                "bad": self._bad,
                "throttled_s": round(self._throttled_s, 3),
                "state_latency_ms": percentiles(list(self._state_ms)),
                "state_gap_ms": percentiles(list(self._state_gap_ms)),
                "ping_echo_ms": percentiles(list(self._ping_echo_ms)),
            }
