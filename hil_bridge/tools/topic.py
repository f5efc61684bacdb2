"""Topic introspection shared by ``echoloop topic`` and ``echoloop bag info``.

:class:`TopicMonitor` subscribes a raw transport to a prefix and feeds one
:class:`~hil_bridge.bus.stats.TopicStats` per topic (counts, rates, gaps, lost and duplicate
messages, epochs: its docstring says how each is counted).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from hil_bridge.bus.codec import Header, decode_topic_header
from hil_bridge.bus.stats import TopicStats
from hil_bridge.bus.transport import Frames, open_transport
from hil_bridge.errors import CodecError

__all__ = ["TopicMonitor"]

#: distinct publishers / frame ids listed per topic (a flood of forged ``src`` stays bounded)
class TopicMonitor:
    """Receive raw frames under ``prefix`` on ``bus``; keep a :class:`TopicStats` per topic.

    ``run(duration_s, on_message=None, max_messages=None)`` blocks; frames that do not decode are
    counted in ``decode_errors``.
    """

    def __init__(self, bus: str, prefix: str = "") -> None:
        self.bus = bus
        self.prefix = prefix
        self.topics: dict[str, TopicStats] = {}
        self.decode_errors = 0

    def run(
        self,
        duration_s: float | None,
        on_message: Callable[[str, Header, Frames, TopicStats], None] | None = None,
        max_messages: int | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> dict[str, TopicStats]:
        deadline = None if duration_s is None else time.monotonic() + duration_s
        seen = 0
        with open_transport(self.bus) as transport:
            transport.subscribe(self.prefix.encode())
            while deadline is None or time.monotonic() < deadline:
                if stop is not None and stop():
                    break
                wait = 0.1 if deadline is None else min(0.1, max(0.0, deadline - time.monotonic()))
                frames = transport.recv(timeout=wait)
                if frames is None:
                    continue
                try:
                    topic, header = decode_topic_header(frames)
                except CodecError:
                    self.decode_errors += 1
                    continue
                stats = self.topics.get(topic)
                if stats is None:
                    stats = self.topics[topic] = TopicStats(topic)
                stats.add(header, len(frames[1]) + len(frames[2]), time.monotonic_ns())
                if on_message is not None:
                    on_message(topic, header, frames, stats)
                seen += 1
                if max_messages is not None and seen >= max_messages:
                    break
        return self.topics
