"""``replay://PATH.mcap[?rate=R&loop=1]``: a read-only bus that plays a recording.

``recv`` returns the recorded messages (topic-filtered like any transport) paced by their
recorded receive times divided by ``rate`` (``rate=0``: as fast as possible), then ``None``
(or the recording again from the start with ``loop=1``). Headers are as recorded except
``pub_ns``, which is the replay's monotonic clock at delivery, so ``seq`` gaps and stamps look as
they did live (each ``loop`` pass counts ``seq`` from the start again: receivers see a new
epoch, :mod:`hil_bridge.bus.seq`). Publishing is accepted and discarded (counted ``discarded``),
so ordinary nodes run unchanged; no subscriber is ever reported. Use it to run tools and
nodes offline::

    echoloop topic hz /glider/0/state --bus "replay://run.mcap?rate=0" --duration 5
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

from hil_bridge.bus.codec import Header, pack_header
from hil_bridge.bus.transport.base import Frames, Transport
from hil_bridge.recording.mcap_scan import check_mcap

__all__ = ["ReplayTransport"]

log = logging.getLogger(__name__)

_Item = tuple[str, Header, bytes, int]


class ReplayTransport(Transport):
    """Read-only transport over an MCAP recording (see the module docstring)."""

    def __init__(self, url: str) -> None:
        super().__init__(url)
        parts = urlsplit(url)
        path = unquote(parts.netloc + parts.path)
        query = parse_qs(parts.query)
        unknown = sorted(set(query) - {"rate", "loop"})
        if unknown:
            raise ValueError(f"unknown option(s) {unknown} in {url!r}; known: ['loop', 'rate']")
        try:
            rate = float(query.get("rate", ["1"])[-1])
        except ValueError:
            raise ValueError(f"rate must be a number >= 0 in {url!r}") from None
        if not rate >= 0:
            raise ValueError(f"rate must be a number >= 0 in {url!r}")
        if not path or not Path(path).is_file():
            raise ValueError(f"replay:// needs an existing MCAP file, got {path!r} in {url!r}")
        check_mcap(path)
        self.path = path
        self.rate = math.inf if rate == 0 else rate
        self.loop = query.get("loop", ["0"])[-1] in ("1", "true", "yes")
        self._wake = threading.Event()
        self._items: Iterator[_Item] | None = None
        self._next: _Item | None = None
        self._t0_wall = 0.0
        self._t0_log: int | None = None
        self._counters["discarded"] = 0

    def _read(self) -> Iterator[_Item]:
        from hil_bridge.recording.bag import BagInfo, read_bag

        warned = False
        while True:
            self._t0_log = None
            info = BagInfo(self.path)
            for m in read_bag(self.path, info=info):
                yield m.topic, m.header, m.payload, m.log_time
            if info.damaged and not warned:  # once, not per loop pass
                warned = True
                if info.scan is not None:
                    log.warning("%s: %s", self.path, info.scan.describe())
            if not self.loop:
                return

    def _send(self, frames: Sequence[bytes]) -> None:
        self._counters["discarded"] += 1

    def _wakeup(self) -> None:
        self._wake.set()

    def _recv_internal(self, timeout: float | None) -> Frames | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        if self._items is None:
            self._items = self._read()
        item = self._next if self._next is not None else next(self._items, None)
        self._next = None
        if item is None:  # end of the recording: behave like a silent bus
            if self._wake.wait(timeout):
                self._wake.clear()
            return None
        topic, h, payload, log_time = item
        if self._t0_log is None:
            self._t0_log, self._t0_wall = log_time, time.monotonic()
        if math.isfinite(self.rate):
            due = self._t0_wall + (log_time - self._t0_log) / 1e9 / self.rate
            wait = due - time.monotonic()
            if deadline is not None:
                wait = min(wait, deadline - time.monotonic())
            woken = wait > 0 and self._wake.wait(wait)
            if woken or time.monotonic() < due:
                self._wake.clear()
                self._next = item  # not due yet: deliver it on a later call
                return None
        header = Header(h.type, h.v, h.seq, h.stamp_ns, time.monotonic_ns(), h.frame_id, h.src)
        return [topic.encode() + b"\0", pack_header(header), payload]
