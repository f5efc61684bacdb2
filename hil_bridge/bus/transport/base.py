"""The transport seam: one small ABC shaped like python-can's ``BusABC``.

Contract of :class:`Transport` (every backend honours it; ``tests/hil_bridge/bus`` checks it):

1. ``publish(frames)`` sends one 3-frame message ``[topic\\0, header, payload]`` to every
   endpoint subscribed to a prefix of its topic frame, this endpoint included. It never blocks
   on a slow or absent subscriber: past the queue bound, messages are dropped (and counted
   where the backend can see it).
2. ``subscribe(prefix, lane=None)`` / ``unsubscribe(prefix)`` select which topic frames
   ``recv`` returns (byte-prefix match on frame 1; subscribe to ``topic + b"\\0"`` for one exact
   topic, ``b""`` for all). Prefixes subscribed with the same ``lane`` key share one queue (in
   arrival order); by default every prefix is its own lane. They may be called from any thread.
3. ``recv(timeout)`` returns the next matching message as a list of 3 ``bytes`` frames, or
   ``None`` when ``timeout`` seconds pass (``None`` waits forever) or :meth:`wakeup` is called.
   One thread at a time may call ``recv``. Messages are queued per lane and the lanes are
   served in turn, so a flood under one prefix cannot hold back another lane; order is kept
   within a lane, not across lanes. (A foreign publisher may send other frame counts;
   receivers check.)
4. ``wait_for_subscriber(topic, timeout)`` returns ``True`` once some endpoint's subscription
   covering ``topic`` is known to reach this endpoint's publications (the slow-joiner guard:
   messages published after it returns ``True`` are delivered to that subscriber).
5. ``on_subscribe`` (settable callable ``prefix -> None``) is called once per subscription a
   remote endpoint makes, after it is in effect; latched publishers re-send their last value
   from it. It runs on a transport-owned or caller thread and must not block.
6. ``close()`` is idempotent; any later ``publish``/``subscribe``/``recv`` raises
   :class:`~hil_bridge.errors.TransportClosed`. ``with`` closes; iteration yields messages
   until closed.
7. ``stats()`` returns counters: ``sent``, ``received``, ``filtered`` and backend ones (e.g.
   ``dropped`` for queue overflow the backend can see).
8. ``reset(prefix)`` discards what is queued in the lane of a subscribed prefix, as far as the
   backend can reach (over ZeroMQ the lane's socket is re-made, so the proxy's queue and the
   kernel buffers behind it go too); messages published from then on arrive. May be called
   from any thread.
9. ``sync(timeout)`` returns ``True`` once every subscription the bus knew when it was called
   reaches this endpoint's publications (``False`` after ``timeout`` s, or as soon as the
   process was asked to stop, :func:`hil_bridge.lifetime.stopping`: a node host whose launcher
   died does not wait out the timeout for a proxy that went with it): a node that syncs
   before it publishes loses nothing to subscribers that were there first, whatever their
   topics. :func:`sync_open` syncs every endpoint this process has open (the launch does, between
   constructing nodes and starting them).

Backends implement ``_send``, ``_recv_internal`` and, where they need them, ``_subscribe``,
``_unsubscribe``, ``_reset``, ``_service``, ``_sync``, ``_wakeup`` and ``_close``; the base owns
timeouts, topic filtering, subscription bookkeeping and shutdown.
"""

from __future__ import annotations

import threading
import time
import weakref
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from types import TracebackType
from typing import ClassVar

from hil_bridge.errors import TransportClosed

__all__ = ["Frames", "Transport", "sync_open"]

Frames = list[bytes]


def _as_prefix(prefix: bytes | str) -> bytes:
    if isinstance(prefix, str):
        return prefix.encode()
    if isinstance(prefix, (bytes, bytearray, memoryview)):
        return bytes(prefix)
    raise TypeError(f"subscription prefix must be bytes or str, got {type(prefix).__name__}")


class Transport(ABC):
    """Publish/receive 3-frame bus messages on topics (see the module docstring's contract)."""

    #: True when the backend needs a running :class:`~hil_bridge.bus.proxy.Proxy` to carry messages.
    NEEDS_PROXY: ClassVar[bool] = False

    def __init__(self, url: str) -> None:
        self.url = url
        self.on_subscribe: Callable[[bytes], None] | None = None
        self._closed = False
        self._close_lock = threading.Lock()
        self._sub_lock = threading.Lock()
        self._prefixes: dict[bytes, int] = {}
        #: the lane key of each subscribed prefix (itself unless ``subscribe(lane=...)``)
        self._lane_of: dict[bytes, bytes] = {}
        self._prefix_tuple: tuple[bytes, ...] = ()
        self._remote: set[bytes] = set()
        self._remote_cond = threading.Condition()
        self._counters: dict[str, int] = {"sent": 0, "received": 0, "filtered": 0}
        _OPEN.add(self)

    # -- backend surface --------------------------------------------------------------------
    @abstractmethod
    def _send(self, frames: Sequence[bytes]) -> None:
        """Send one message without blocking on subscribers."""

    @abstractmethod
    def _recv_internal(self, timeout: float | None) -> Frames | None:
        """Next message (unfiltered is fine) or ``None`` after ``timeout`` s or a wakeup."""

    def _subscribe(self, prefix: bytes) -> None:
        """Start delivering ``prefix`` to this endpoint, queued in lane ``self._lane_of[prefix]``
        (called once per distinct prefix)."""
        return

    def _unsubscribe(self, prefix: bytes) -> None:
        """Stop delivering ``prefix`` (called when its last subscription goes)."""
        return

    def _reset(self, prefix: bytes) -> None:
        """Drop what is queued in the lane of ``prefix`` (its subscriptions stay)."""
        return

    def _service(self, timeout: float) -> None:
        """Process subscription events for up to ``timeout`` s (via :meth:`_remote_subscribed`)."""
        if timeout > 0:
            with self._remote_cond:
                self._remote_cond.wait(timeout)

    def _sync(self, timeout: float) -> bool:
        """Contract 9 (a backend that delivers synchronously is always in sync)."""
        return True

    def _wakeup(self) -> None:
        """Make a blocked ``_recv_internal`` return ``None`` promptly."""
        return

    def _close(self) -> None:
        """Release the backend's resources (called once)."""
        return

    # -- shared machinery -------------------------------------------------------------------
    def _remote_subscribed(self, prefix: bytes) -> None:
        """Backends call this for each subscription a remote endpoint makes."""
        with self._remote_cond:
            self._remote.add(prefix)
            self._remote_cond.notify_all()
        callback = self.on_subscribe
        if callback is not None:
            callback(prefix)

    def _check_open(self) -> None:
        if self._closed:
            raise TransportClosed(f"transport {self.url!r} is closed")

    @property
    def closed(self) -> bool:
        return self._closed

    def publish(self, frames: Sequence[bytes]) -> None:
        """Send one 3-frame message (contract 1)."""
        self._check_open()
        if len(frames) != 3:
            raise ValueError(
                f"a bus message has 3 frames [topic, header, payload], got {len(frames)}"
            )
        self._send(frames)
        self._counters["sent"] += 1

    def subscribe(self, prefix: bytes | str, *, lane: bytes | str | None = None) -> None:
        """Receive topic frames starting with ``prefix``, queued in ``lane`` (default: a lane of
        its own; the first subscription of a prefix decides) (contract 2; counted per call)."""
        self._check_open()
        p = _as_prefix(prefix)
        with self._sub_lock:
            count = self._prefixes.get(p, 0)
            self._prefixes[p] = count + 1
            self._prefix_tuple = tuple(self._prefixes)
            if count == 0:
                self._lane_of[p] = p if lane is None else _as_prefix(lane)
                self._subscribe(p)

    def reset(self, prefix: bytes | str) -> None:
        """Discard the messages queued under subscribed ``prefix`` (contract 8); the
        subscription stays and new messages keep coming."""
        self._check_open()
        p = _as_prefix(prefix)
        with self._sub_lock:
            if p not in self._prefixes:
                raise ValueError(f"not subscribed to {p!r}")
        self._reset(p)
        self._counters["resets"] = self._counters.get("resets", 0) + 1

    def unsubscribe(self, prefix: bytes | str) -> None:
        """Undo one :meth:`subscribe` of ``prefix``; unknown prefixes raise ``ValueError``."""
        self._check_open()
        p = _as_prefix(prefix)
        with self._sub_lock:
            count = self._prefixes.get(p, 0)
            if count == 0:
                raise ValueError(f"not subscribed to {p!r}")
            if count == 1:
                del self._prefixes[p]
                self._prefix_tuple = tuple(self._prefixes)
                self._unsubscribe(p)
                del self._lane_of[p]
            else:
                self._prefixes[p] = count - 1

    def recv(self, timeout: float | None = None) -> Frames | None:
        """Next message matching a subscription, or ``None`` (contract 3)."""
        if self._closed:
            raise TransportClosed(f"transport {self.url!r} is closed")
        deadline: float | None = None
        remaining = timeout
        while True:
            frames = self._recv_internal(remaining)
            if frames is None or self._closed:
                return None
            if frames[0].startswith(self._prefix_tuple):
                self._counters["received"] += 1
                return frames
            self._counters["filtered"] += 1
            if timeout is not None:  # the deadline only matters once a message was filtered
                if deadline is None:
                    deadline = time.monotonic() + timeout
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None

    def has_subscriber(self, topic: str) -> bool:
        """True if a remote subscription covering ``topic`` is known (no waiting)."""
        frame = topic.encode() + b"\0"
        with self._remote_cond:
            return any(frame.startswith(p) for p in self._remote)

    def wait_for_subscriber(self, topic: str, timeout: float) -> bool:
        """Block until :meth:`has_subscriber` (contract 4) or ``timeout`` s; return which."""
        self._check_open()
        deadline = time.monotonic() + timeout
        while not self.has_subscriber(topic):
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self._closed:
                return False
            self._service(min(remaining, 0.05))
        return True

    def sync(self, timeout: float) -> bool:
        """Block until this endpoint's publications reach every subscription the bus knew when
        called, or ``timeout`` s; return which (contract 9)."""
        self._check_open()
        return self._sync(timeout)

    def service(self, timeout: float = 0.0) -> None:
        """Process pending subscription events (latched re-sends), waiting up to ``timeout``."""
        if not self._closed:
            self._service(timeout)

    def wakeup(self) -> None:
        """Make a ``recv`` blocked in another thread return ``None`` promptly."""
        if not self._closed:
            self._wakeup()

    def stats(self) -> dict[str, int]:
        """Counters (contract 7)."""
        return dict(self._counters)

    def close(self) -> None:
        """Release resources; idempotent (contract 6)."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        _OPEN.discard(self)
        with self._remote_cond:
            self._remote_cond.notify_all()
        self._close()

    def __enter__(self) -> Transport:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __iter__(self) -> Iterator[Frames]:
        while not self._closed:
            frames = self.recv(timeout=0.1)
            if frames is not None:
                yield frames

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"{type(self).__name__}({self.url!r}, {state})"


#: every transport of this process not closed yet (weakly: a dropped one is gone)
_OPEN: weakref.WeakSet[Transport] = weakref.WeakSet()


def sync_open(timeout: float, *, url: str | None = None) -> list[str]:
    """:meth:`Transport.sync` every transport this process has open (on bus ``url`` only, if
    given), within ``timeout`` s in all; the URLs of those that did not get in sync (closed
    meanwhile ones are skipped)."""
    deadline = time.monotonic() + timeout
    late: list[str] = []
    for transport in [t for t in list(_OPEN) if url is None or t.url == url]:
        try:
            if not transport.sync(max(0.0, deadline - time.monotonic())):
                late.append(transport.url)
        except TransportClosed:
            continue
    return late
