"""``mem://name``: an in-process bus for unit tests (python-can's ``VirtualBus`` shape).

Every endpoint opened on the same ``name`` in one process joins one channel; a message published
on any endpoint is delivered to every endpoint (itself included) with a matching subscription.
Each endpoint keeps one bounded keep-last queue per lane (a subscribed prefix, or the prefixes
subscribed with one ``lane`` key; ``?depth=N``, default 1000; a message goes to the lane of the
first of its prefixes that matches): when a slow reader lets one
fill, its oldest message is discarded and counted as ``dropped``, and the publisher never
waits. ``recv`` serves the queues in turn, so a flood under one prefix cannot hold back another
(as over ZeroMQ: order is kept within a prefix, not across prefixes). Subscriptions take
effect synchronously, so ``wait_for_subscriber`` returns at once when one exists; a new
subscription is announced to every endpoint's ``on_subscribe`` (latching).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Sequence
from urllib.parse import parse_qs, urlsplit

from hil_bridge.bus.transport.base import Frames, Transport

__all__ = ["MemTransport"]

_CHANNELS: dict[str, _Channel] = {}
_CHANNELS_LOCK = threading.Lock()


class _Channel:
    def __init__(self, name: str) -> None:
        self.name = name
        self.endpoints: tuple[MemTransport, ...] = ()


def _parse(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    if parts.scheme != "mem" or not parts.netloc:
        raise ValueError(f"expected 'mem://NAME[?depth=N]', got {url!r}")
    query = parse_qs(parts.query, strict_parsing=False)
    unknown = set(query) - {"depth"}
    if unknown:
        raise ValueError(f"unknown option(s) {sorted(unknown)} in {url!r}; known: ['depth']")
    depth = 1000
    if "depth" in query:
        try:
            depth = int(query["depth"][-1])
        except ValueError:
            raise ValueError(f"depth must be an int >= 1 in {url!r}") from None
        if depth < 1:
            raise ValueError(f"depth must be an int >= 1 in {url!r}")
    return parts.netloc, depth


class MemTransport(Transport):
    """One endpoint of an in-process channel (see the module docstring)."""

    def __init__(self, url: str) -> None:
        super().__init__(url)
        name, depth = _parse(url)
        self.depth = depth
        self._queues: dict[bytes, deque[Frames]] = {}
        self._rotation: deque[bytes] = deque()
        self._cond = threading.Condition()
        self._wake = False
        self._counters["dropped"] = 0
        with _CHANNELS_LOCK:
            channel = _CHANNELS.get(name)
            if channel is None:
                channel = _CHANNELS[name] = _Channel(name)
            channel.endpoints = (*channel.endpoints, self)
            peers = channel.endpoints
        self._channel = channel
        for peer in peers:
            if peer is not self:
                for prefix in tuple(peer._prefixes):
                    self._remote_subscribed(prefix)

    def _deliver(self, frames: Frames) -> None:
        topic = frames[0]
        for prefix in self._prefix_tuple:
            if topic.startswith(prefix):
                break
        else:
            return
        lane = self._lane_of.get(prefix, prefix)
        with self._cond:
            queue = self._queues.get(lane)
            if queue is None:
                queue = self._queues[lane] = deque()
            if not queue:
                self._rotation.append(lane)
            elif len(queue) >= self.depth:
                queue.popleft()
                self._counters["dropped"] += 1
            queue.append(frames)
            self._cond.notify()

    def _send(self, frames: Sequence[bytes]) -> None:
        message = [bytes(f) for f in frames]
        for endpoint in self._channel.endpoints:
            endpoint._deliver(message)

    def _recv_internal(self, timeout: float | None) -> Frames | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._rotation:
                if self._wake or self._closed:
                    self._wake = False
                    return None
                if deadline is None:
                    self._cond.wait()
                else:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return None
                    self._cond.wait(remaining)
            prefix = self._rotation.popleft()
            queue = self._queues[prefix]
            frames = queue.popleft()
            if queue:
                self._rotation.append(prefix)
            return frames

    def _reset(self, prefix: bytes) -> None:
        lane = self._lane_of[prefix]
        with self._cond:
            queue = self._queues.get(lane)
            if queue:
                self._counters["dropped"] += len(queue)
                queue.clear()
                self._rotation.remove(lane)

    def _unsubscribe(self, prefix: bytes) -> None:
        lane = self._lane_of[prefix]
        if any(k == lane for p, k in self._lane_of.items() if p != prefix):
            return  # the lane still serves another prefix
        with self._cond:
            if self._queues.pop(lane, None) and lane in self._rotation:
                self._rotation.remove(lane)

    def _subscribe(self, prefix: bytes) -> None:
        for endpoint in self._channel.endpoints:
            endpoint._remote_subscribed(prefix)

    def _wakeup(self) -> None:
        with self._cond:
            self._wake = True
            self._cond.notify_all()

    def _close(self) -> None:
        with _CHANNELS_LOCK:
            channel = self._channel
            channel.endpoints = tuple(e for e in channel.endpoints if e is not self)
            if not channel.endpoints and _CHANNELS.get(channel.name) is channel:
                del _CHANNELS[channel.name]
        with self._cond:
            self._queues.clear()
            self._rotation.clear()
            self._cond.notify_all()
