"""Statistics of a topic and of latencies, kept by every tool, recorder and monitor of the bus.

:class:`TopicStats` folds the headers seen on one topic into counts, rates and gaps:

- ``gaps`` / ``lost``: publisher ``seq`` jumps (per publisher ``src``): a jump from 7 to 10 is one
  gap of 2 lost messages; repeats (latched re-sends, retransmissions) count as ``duplicates``;
  a sequence that goes back or jumps by more than :data:`~hil_bridge.bus.seq.MAX_GAP` (a restart,
  a wrap, a forged value) starts a new ``epochs`` and is counted like any other message
  (:class:`~hil_bridge.bus.seq.SeqTracker`);
- ``rate_hz``: messages per second of the publishers' sim time (from ``stamp_ns``), and
  ``recv_rate_hz`` per second of receive time; ``bandwidth_bps`` payload+header bytes per
  receive second.

:func:`percentiles` summarises a list of latencies or gaps.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil_bridge.bus.codec import Header
from hil_bridge.bus.seq import SeqTracker, Verdict

__all__ = ["TopicStats", "percentiles"]


def percentiles(values: Sequence[float]) -> dict[str, float]:
    """``{"n", "p50", "p90", "p99", "max"}`` of ``values`` (NaN percentiles when empty)."""
    if not values:
        return {"n": 0, "p50": math.nan, "p90": math.nan, "p99": math.nan, "max": math.nan}
    a = np.asarray(values, dtype=np.float64)
    p50, p90, p99 = np.percentile(a, [50, 90, 99])
    return {"n": int(a.size), "p50": float(p50), "p90": float(p90), "p99": float(p99),
            "max": float(a.max())}


_MAX_NAMES = 256


@dataclass
class TopicStats:
    """Running statistics of one topic (see the module docstring)."""

    topic: str
    types: set[str] = field(default_factory=set)
    count: int = 0
    bytes: int = 0
    publishers: set[str] = field(default_factory=set)
    frame_ids: set[str] = field(default_factory=set)
    first_stamp_ns: int | None = None
    last_stamp_ns: int | None = None
    first_recv_ns: int | None = None
    last_recv_ns: int | None = None
    _seq: SeqTracker = field(default_factory=SeqTracker)
    _intervals_ns: list[int] = field(default_factory=list)

    def add(self, header: Header, nbytes: int, recv_ns: int) -> None:
        """Fold in one message: its header, its size in bytes, its receive time (ns)."""
        self.types.add(header.type)
        if len(self.publishers) < _MAX_NAMES:
            self.publishers.add(header.src)
        if len(self.frame_ids) < _MAX_NAMES:
            self.frame_ids.add(header.frame_id)
        verdict = self._seq.observe(header.src, header.seq, header.stamp_ns, header.pub_ns)
        if verdict is Verdict.DUPLICATE:
            return
        self.count += 1
        self.bytes += nbytes
        if self.last_stamp_ns is not None and len(self.publishers) == 1:
            self._intervals_ns.append(header.stamp_ns - self.last_stamp_ns)
            if len(self._intervals_ns) > 10_000:
                del self._intervals_ns[:5_000]
        if self.first_stamp_ns is None:
            self.first_stamp_ns = header.stamp_ns
            self.first_recv_ns = recv_ns
        self.last_stamp_ns = header.stamp_ns
        self.last_recv_ns = recv_ns

    @property
    def duplicates(self) -> int:
        return self._seq.duplicates

    @property
    def gaps(self) -> int:
        return self._seq.gaps

    @property
    def lost(self) -> int:
        return self._seq.lost

    @property
    def epochs(self) -> int:
        return self._seq.epochs

    @property
    def rate_hz(self) -> float | None:
        """Messages per second of sim time (None until two messages with distinct stamps)."""
        if self.first_stamp_ns is None or self.last_stamp_ns is None or self.count < 2:
            return None
        span = self.last_stamp_ns - self.first_stamp_ns
        return (self.count - 1) / (span / 1e9) if span > 0 else None

    @property
    def recv_rate_hz(self) -> float | None:
        if self.first_recv_ns is None or self.last_recv_ns is None or self.count < 2:
            return None
        span = self.last_recv_ns - self.first_recv_ns
        return (self.count - 1) / (span / 1e9) if span > 0 else None

    @property
    def bandwidth_bps(self) -> float | None:
        if self.first_recv_ns is None or self.last_recv_ns is None or self.count < 2:
            return None
        span = self.last_recv_ns - self.first_recv_ns
        return self.bytes / (span / 1e9) if span > 0 else None

    def interval_summary(self) -> dict[str, float] | None:
        """min/mean/max/std of stamp intervals in seconds (single-publisher topics)."""
        if not self._intervals_ns:
            return None
        xs = [x / 1e9 for x in self._intervals_ns]
        return {
            "min_s": min(xs),
            "mean_s": statistics.fmean(xs),
            "max_s": max(xs),
            "std_s": statistics.pstdev(xs),
        }

    def as_dict(self) -> dict[str, Any]:
        return {
            "topic": self.topic,
            "types": sorted(self.types),
            "count": self.count,
            "bytes": self.bytes,
            "duplicates": self.duplicates,
            "gaps": self.gaps,
            "lost": self.lost,
            "epochs": self.epochs,
            "publishers": sorted(self.publishers),
            "frame_ids": sorted(self.frame_ids),
            "rate_hz": self.rate_hz,
            "recv_rate_hz": self.recv_rate_hz,
            "bandwidth_bps": self.bandwidth_bps,
            "first_stamp_ns": self.first_stamp_ns,
            "last_stamp_ns": self.last_stamp_ns,
            "intervals": self.interval_summary(),
        }
