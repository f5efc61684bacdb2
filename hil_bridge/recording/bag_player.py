"""Replay of a bag onto the bus (``echoloop bag play``): :class:`Player`.

Replay re-publishes each message with its recorded header (type, v, seq, stamp_ns, frame_id,
src) and payload, a fresh ``pub_ns``, paced by ``log_time`` / ``rate``: a recording of a replay
has byte-identical payloads and identical seq and stamps.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from hil_bridge.bus.codec import Header, encode, pack_header, topic_frame, validate_topic
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.messages import Clock
from hil_bridge.bus.transport import Transport, open_transport
from hil_bridge.recording.bag import BagInfo, read_bag
from hil_bridge.recording.mcap_scan import check_mcap

__all__ = ["Player"]


class Player:
    """Re-publish a bag on the bus (launchable-like: ``start()``, ``stop()``, ``stats()``).

    ``Player(path, *, bus=None, rate=1.0, loop=False, start_offset_s=0.0, topics=None,
    clock=False, clock_hz=100.0, wait_for_subscribers_s=0.0)``. ``rate`` scales the recorded
    receive timing (``math.inf``: as fast as possible). ``loop`` repeats (each pass re-sends
    under ``src`` suffixed ``~loopK`` so receivers do not drop it as duplicates). ``clock``
    publishes ``/clock`` from the recorded stamps (at most ``clock_hz`` per wall second) and
    leaves out recorded ``/clock``. ``wait_for_subscribers_s`` > 0 first waits (up to that long)
    until every played topic has a subscriber. :meth:`wait` blocks until playback ends.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        bus: str | None = None,
        rate: float = 1.0,
        loop: bool = False,
        start_offset_s: float = 0.0,
        topics: Iterable[str] | None = None,
        clock: bool = False,
        clock_hz: float = 100.0,
        wait_for_subscribers_s: float = 0.0,
        name: str = "player",
    ) -> None:
        if not (isinstance(rate, (int, float)) and rate > 0):
            raise ValueError(f"rate must be > 0 (math.inf: as fast as possible), got {rate!r}")
        if start_offset_s < 0:
            raise ValueError(f"start_offset_s must be >= 0, got {start_offset_s}")
        if not clock_hz > 0:
            raise ValueError(f"clock_hz must be > 0, got {clock_hz}")
        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"bag {str(self.path)!r} does not exist")
        check_mcap(self.path)
        self.bus = bus if bus is not None else current_domain().bus_url
        self.rate = float(rate)
        self.loop = loop
        self.start_offset_s = start_offset_s
        self.topics = None if topics is None else [validate_topic(t) for t in topics]
        self.clock = clock
        self.clock_hz = clock_hz
        self.wait_for_subscribers_s = wait_for_subscribers_s
        self.name = name
        self._stop = threading.Event()
        self._done = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._transport: Transport | None = None
        self._stopped = False
        self._counters = {"published": 0, "passes": 0, "clock_published": 0}
        self.truncated = False
        #: what the last pass read (corrupt chunks skipped, truncation)
        self.info: BagInfo | None = None
        self.error: BaseException | None = None

    def start(self) -> Player:
        with self._lock:
            if self._thread is not None or self._stopped:
                return self
            self._transport = open_transport(self.bus)
            self._thread = threading.Thread(
                target=self._run, args=(self._transport,), name=f"{self.name}-play", daemon=True
            )
            self._thread.start()
        return self

    def _played_topics(self) -> list[str]:
        topics = {m.topic for m in read_bag(self.path, self.topics)}
        if self.clock:
            topics.discard("/clock")
            topics.add("/clock")
        return sorted(topics)

    def _run(self, transport: Transport) -> None:
        try:
            if self.wait_for_subscribers_s > 0:
                deadline = time.monotonic() + self.wait_for_subscribers_s
                for topic in self._played_topics():
                    transport.wait_for_subscriber(topic, max(0.0, deadline - time.monotonic()))
            clock_seq = 0
            passes = 0
            while not self._stop.is_set():
                clock_seq = self._play_once(transport, passes, clock_seq)
                passes += 1
                self._counters["passes"] = passes
                if not self.loop:
                    break
        except BaseException as exc:
            self.error = exc
            raise
        finally:
            self._done.set()

    def _play_once(self, transport: Transport, passes: int, clock_seq: int) -> int:
        info = BagInfo(str(self.path))
        first_log: int | None = None
        wall0 = time.monotonic()
        clock_period = 1.0 / self.clock_hz
        next_clock = 0.0
        last_clock_stamp = -1
        suffix = f"~loop{passes}" if passes else ""
        for m in read_bag(self.path, self.topics, info=info):
            if self._stop.is_set():
                break
            if first_log is None:
                first_log = m.log_time
            offset_s = (m.log_time - first_log) / 1e9
            if offset_s < self.start_offset_s:
                continue
            if self.clock and m.topic == "/clock":
                continue
            if math.isfinite(self.rate):
                due = wall0 + (offset_s - self.start_offset_s) / self.rate
                delay = due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    break
            now = time.monotonic()
            if self.clock and m.header.stamp_ns > last_clock_stamp and now >= next_clock:
                clock_msg = Clock(stamp_ns=m.header.stamp_ns)
                transport.publish(encode("/clock", clock_msg, seq=clock_seq,
                                         pub_ns=time.monotonic_ns(), src=f"{self.name}/clock"))
                clock_seq += 1
                last_clock_stamp = m.header.stamp_ns
                next_clock = now + clock_period
                self._counters["clock_published"] += 1
            header = Header(m.header.type, m.header.v, m.header.seq, m.header.stamp_ns,
                            time.monotonic_ns(), m.header.frame_id, m.header.src + suffix)
            transport.publish([topic_frame(m.topic), pack_header(header), m.payload])
            self._counters["published"] += 1
        self.truncated = self.truncated or info.truncated
        self.info = info
        return clock_seq

    def wait(self, timeout: float | None = None) -> bool:
        """True once playback ended (end of bag, or stop); False after ``timeout`` s."""
        return self._done.wait(timeout)

    def stop(self) -> None:
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
            thread, transport = self._thread, self._transport
        self._stop.set()
        if thread is not None:
            thread.join()
        if transport is not None:
            transport.close()

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self._counters)
        out["truncated"] = self.truncated
        return out

