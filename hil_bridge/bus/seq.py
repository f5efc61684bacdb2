"""Per-publisher sequence accounting that no message on the bus can freeze.

Receivers count the header ``seq`` per publisher ``src`` to see losses and repeats. ``src`` and
``seq`` are visible on the bus and may be forged, wrap, or restart (a publisher restarted under
the same ``src``), so a :class:`SeqTracker` never lets one value decide the fate of the messages
after it. Each message gets one :class:`Verdict`:

- ``DUPLICATE`` — its identity ``(seq, stamp_ns, pub_ns)`` was seen among the last ``window``
  messages of this publisher: a true re-send (latched re-send, ``COMMAND`` retransmission, which
  repeat the frames byte for byte). The only verdict that is not delivered.
- ``NEXT`` — ``seq == last + 1``.
- ``GAP`` — ``last + 1 < seq <= last + 1 + max_gap``: delivered, ``seq - last - 1`` lost.
- ``LATE`` — reliable streams only: ``last - window < seq <= last`` and not a duplicate (a
  message that overtook a retransmission); delivered, ``last`` unchanged.
- ``EPOCH`` — anything else (the sequence went back, as after a restart or a wrap, or jumped
  further than ``max_gap``, as a forged value does): delivered and counted; it becomes ``last``,
  so the real stream is back in order at its next message.

A forged message therefore costs at most the one real message that carries the same identity,
never the rest of the stream, and a forged jump adds at most ``max_gap`` to the loss count.
Memory is bounded: ``window`` identities per publisher and ``max_sources`` publishers per
tracker (the least recently heard one is forgotten first).
"""

from __future__ import annotations

from collections import OrderedDict, deque
from dataclasses import dataclass, field
from enum import Enum

__all__ = ["MAX_GAP", "MAX_SOURCES", "SeqTracker", "Verdict"]

#: a forward jump of more than this many messages is a new epoch, not a loss
MAX_GAP = 1 << 16
#: publishers remembered per tracker (least recently heard forgotten first)
MAX_SOURCES = 1024
_WINDOW_BEST_EFFORT = 64
_WINDOW_RELIABLE = 1024


class Verdict(Enum):
    """What a :class:`SeqTracker` makes of one message (see the module docstring)."""

    NEXT = "next"
    GAP = "gap"
    LATE = "late"
    EPOCH = "epoch"
    DUPLICATE = "duplicate"

    @property
    def delivered(self) -> bool:
        return self is not Verdict.DUPLICATE


@dataclass(slots=True)
class _Source:
    last: int
    seen: set[tuple[int, int, int]] = field(default_factory=set)
    order: deque[tuple[int, int, int]] = field(default_factory=deque)


class SeqTracker:
    """Classify messages per publisher (module docstring); keeps the counters ``gaps``,
    ``lost``, ``duplicates``, ``epochs`` and ``late``."""

    def __init__(
        self, *, reliable: bool = False, max_gap: int = MAX_GAP,
        window: int | None = None, max_sources: int = MAX_SOURCES,
    ) -> None:
        if max_gap < 0 or max_sources < 1:
            raise ValueError(f"max_gap must be >= 0 and max_sources >= 1, got {max_gap}, "
                             f"{max_sources}")
        self.reliable = reliable
        self.max_gap = max_gap
        self.window = window if window is not None else (
            _WINDOW_RELIABLE if reliable else _WINDOW_BEST_EFFORT)
        if self.window < 1:
            raise ValueError(f"window must be >= 1, got {self.window}")
        self.max_sources = max_sources
        self._sources: OrderedDict[str, _Source] = OrderedDict()
        self.gaps = 0
        self.lost = 0
        self.duplicates = 0
        self.epochs = 0
        self.late = 0

    def observe(self, src: str, seq: int, stamp_ns: int = 0, pub_ns: int = 0) -> Verdict:
        """Classify one message of publisher ``src`` and update the counters."""
        ident = (seq, stamp_ns, pub_ns)
        sources = self._sources
        state = sources.get(src)
        if state is None:
            if len(sources) >= self.max_sources:
                sources.popitem(last=False)
            state = sources[src] = _Source(seq)
            verdict = Verdict.NEXT
        else:
            sources.move_to_end(src)
            if ident in state.seen:
                self.duplicates += 1
                return Verdict.DUPLICATE
            last = state.last
            if seq == last + 1:
                verdict = Verdict.NEXT
            elif last + 1 < seq <= last + 1 + self.max_gap:
                verdict = Verdict.GAP
                if not self.reliable:
                    self.gaps += 1
                    self.lost += seq - last - 1
            elif self.reliable and last - self.window < seq <= last:
                verdict = Verdict.LATE
                self.late += 1
            else:
                verdict = Verdict.EPOCH
                self.epochs += 1
            if verdict is not Verdict.LATE:
                state.last = seq
        state.seen.add(ident)
        state.order.append(ident)
        if len(state.order) > self.window:
            state.seen.discard(state.order.popleft())
        return verdict

    @property
    def sources(self) -> int:
        """Publishers currently remembered."""
        return len(self._sources)
