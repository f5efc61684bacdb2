"""``tcp://`` and ``ipc://``: the ZeroMQ bus through the XSUB/XPUB
:class:`~hil_bridge.bus.proxy.Proxy`.

One URL names both proxy endpoints. It is the **publish** endpoint (the proxy's XSUB); the
**subscribe** endpoint (the proxy's XPUB) is, unless ``?sub=URL`` names it:

- ``tcp://HOST:PORT`` → ``tcp://HOST:PORT+1`` (the default bus ``tcp://127.0.0.1:7400`` subscribes
  on 7401, as ``docs/spec/protocols.md`` §1 says);
- ``ipc://PATH`` → ``ipc://PATH.sub``.

Options (query string): ``sub=URL``; ``hwm=N`` (per-socket queue bound in messages, default
1000); ``curve_server=FILE`` (the proxy's public key, a ``zmq.auth`` ``.key`` file) with
``curve_client=FILE`` (this client's ``.key_secret`` file) to talk to a CURVE-secured proxy.

Publishing uses an XPUB socket (connected to the proxy's XSUB) so the publisher *sees* the
subscriptions the proxy forwards (the proxy's XPUB is verbose): that gives
``wait_for_subscriber`` (no slow-joiner loss without sleeping) and ``on_subscribe`` (latching).
``sync`` (contract 9) subscribes a unique mark under ``/_echoloop/sync/`` on a socket of its
own and on every lane, and waits until its own publish socket sees each of them forwarded by the
proxy (verbose XPUB: every subscription reaches every publisher, this endpoint's included).
Each pipe keeps order, so by then every earlier subscription of every lane is at the proxy and
forwarded to every publisher connected to it, and the publish socket holds every subscription
the proxy held when it connected. The marks are dropped afterwards; echoloop endpoints never
report subscriptions under ``/_echoloop/`` (nothing is published there).
A full queue drops (ZeroMQ HWM semantics) and never blocks the publisher; the receiving node
counts the loss from publisher ``seq`` gaps.

Receiving: every lane (a subscribed prefix, or the prefixes subscribed with one ``lane`` key)
has its own SUB socket, i.e. its own queue (bounded by ``hwm``) and connection to the proxy;
``recv`` serves the lanes in turn, one message each, so a flood under one prefix waits its turn
instead of holding back the clock or another topic. Order is kept within a lane, not across
lanes.

Threading: ``publish`` is safe from any thread (a lock guards the publish socket);
``subscribe`` is safe from any thread (applied by the receiving thread, which it wakes);
one thread at a time calls ``recv``.

Closing: ``close()`` returns at once. Messages still queued on the publish socket keep being
delivered by ZeroMQ's I/O thread for up to ``PUB_LINGER_MS`` (so a publisher that closes right
after publishing does not lose its tail); receive-side sockets drop what is queued.
"""

from __future__ import annotations

import itertools
import math
import os
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast
from urllib.parse import parse_qs, urlsplit

import zmq

from hil_bridge.bus.transport.base import Frames, Transport
from hil_bridge.lifetime import stopping

#: how long messages queued on a closed publish socket are still delivered (milliseconds)
PUB_LINGER_MS = 1000

__all__ = ["ZmqEndpoints", "ZmqTransport", "parse_zmq_url"]

_WAKE_IDS = itertools.count()
#: with a lane that never runs dry, the others are polled at least every this many messages
_POLL_EVERY = 16
#: a lane operation besides SUBSCRIBE / UNSUBSCRIBE: re-make the socket (drop its backlog)
_RESET = -1
#: subscriptions under this prefix are the transport's own (sync marks): never reported
_OWN_TOPICS = b"/_echoloop/"
_SYNC_IDS = itertools.count()
#: how long a sync waits for subscription events at a time (seconds)
_SYNC_POLL_S = 0.005
_KNOWN_OPTIONS = ("curve_client", "curve_server", "hwm", "sub")


@dataclass(frozen=True, slots=True)
class ZmqEndpoints:
    """The two proxy endpoints named by one bus URL, plus its options."""

    pub: str
    sub: str
    hwm: int = 1000
    curve_server: str | None = None
    curve_client: str | None = None


def _default_sub(pub: str) -> str:
    parts = urlsplit(pub)
    if parts.scheme == "tcp":
        host, sep, port = parts.netloc.rpartition(":")
        if not sep or not port.isdigit():
            raise ValueError(f"expected 'tcp://HOST:PORT', got {pub!r}")
        if int(port) == 0:
            raise ValueError(f"port 0 in {pub!r}: give the proxy's real ports (Proxy.url)")
        return f"tcp://{host}:{int(port) + 1}"
    if parts.scheme == "ipc":
        return pub + ".sub"
    raise ValueError(f"expected a tcp:// or ipc:// URL, got {pub!r}")


def parse_zmq_url(url: str) -> ZmqEndpoints:
    """Split a bus URL into :class:`ZmqEndpoints` (``ValueError`` naming the bad part)."""
    base, _, query = url.partition("?")
    scheme = urlsplit(base).scheme
    if scheme not in ("tcp", "ipc"):
        raise ValueError(f"expected a tcp:// or ipc:// bus URL, got {url!r}")
    options = parse_qs(query, keep_blank_values=True)
    unknown = sorted(set(options) - set(_KNOWN_OPTIONS))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} in {url!r}; known: {list(_KNOWN_OPTIONS)}")

    def opt(name: str) -> str | None:
        return options[name][-1] if name in options else None

    sub = opt("sub") or _default_sub(base)
    if urlsplit(sub).scheme not in ("tcp", "ipc"):
        raise ValueError(f"sub= must be a tcp:// or ipc:// URL, got {sub!r}")
    hwm_text = opt("hwm")
    hwm = 1000
    if hwm_text is not None:
        if not hwm_text.isdigit() or int(hwm_text) < 1:
            raise ValueError(f"hwm must be an int >= 1, got {hwm_text!r} in {url!r}")
        hwm = int(hwm_text)
    server, client = opt("curve_server"), opt("curve_client")
    if (server is None) != (client is None):
        raise ValueError(f"give both curve_server= and curve_client= or neither in {url!r}")
    return ZmqEndpoints(base, sub, hwm, server, client)


_CurveKeys = tuple[bytes, bytes, bytes]


def _load_curve(ends: ZmqEndpoints) -> _CurveKeys | None:
    """(server public, client public, client secret) of a CURVE client URL, else None."""
    if ends.curve_server is None or ends.curve_client is None:
        return None
    from hil_bridge.bus.security import read_public_key, read_secret_key

    client_public, client_secret = read_secret_key(ends.curve_client)
    return read_public_key(ends.curve_server), client_public, client_secret


def _apply_curve(sock: zmq.Socket, keys: _CurveKeys | None) -> None:
    if keys is not None:
        sock.curve_serverkey, sock.curve_publickey, sock.curve_secretkey = keys


class ZmqTransport(Transport):
    """A bus endpoint on a ZeroMQ XSUB/XPUB proxy (see the module docstring)."""

    NEEDS_PROXY = True

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self.endpoints = ends = parse_zmq_url(url)
        self._curve = _load_curve(ends)
        self._ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
        self._pub_lock = threading.Lock()
        self._rx_lock = threading.Lock()
        self._rx_done = threading.Condition(self._rx_lock)
        self._in_recv = False
        self._closing = False
        self._wake_flag = False
        self._pending: list[tuple[int, bytes, bytes]] = []
        #: the marks of the syncs under way, and those the publish socket has seen
        self._sync_want: set[bytes] = set()
        self._own_seen: set[bytes] = set()
        #: one SUB socket per lane (its own queue) with the prefixes it subscribes, and the
        #: sockets known to hold messages, served in turn
        self._lanes: dict[bytes, zmq.Socket[bytes]] = {}
        self._lane_prefixes: dict[bytes, list[bytes]] = {}
        self._rotation: deque[zmq.Socket[bytes]] = deque()
        self._since_poll = 0
        pub = self._ctx.socket(zmq.XPUB)
        wake_rx = self._ctx.socket(zmq.PAIR)
        wake_tx = self._ctx.socket(zmq.PAIR)
        sockets = (pub, wake_rx, wake_tx)
        try:
            for sock in sockets:
                sock.linger = 0
            pub.setsockopt(zmq.XPUB_VERBOSE, 1)
            pub.sndhwm = ends.hwm
            _apply_curve(pub, self._curve)
            wake = f"inproc://hil-bridge-wake-{next(_WAKE_IDS)}"
            wake_rx.bind(wake)
            wake_tx.connect(wake)
            try:
                pub.connect(ends.pub)
            except zmq.ZMQError as exc:
                raise ValueError(f"cannot connect to {ends.pub!r}: {exc.strerror}") from None
        except (zmq.ZMQError, OSError, ValueError):
            for sock in sockets:
                sock.close(0)
            raise
        self._pub, self._wake_rx, self._wake_tx = pub, wake_rx, wake_tx
        self._poller = zmq.Poller()
        self._poller.register(wake_rx, zmq.POLLIN)

    # -- publishing -------------------------------------------------------------------------
    def _send(self, frames: Sequence[bytes]) -> None:
        with self._pub_lock:
            self._pub.send_multipart(frames)

    def _service(self, timeout: float) -> None:
        events: list[bytes] = []
        with self._pub_lock:
            if self._closed:
                return
            wait_ms = int(min(timeout, 0.002) * 1000)
            while self._pub.poll(wait_ms, zmq.POLLIN):
                wait_ms = 0
                msg = self._pub.recv(zmq.NOBLOCK)
                if msg[:1] == b"\x01":
                    events.append(msg[1:])
        for prefix in events:
            if prefix.startswith(_OWN_TOPICS):
                with self._remote_cond:
                    if prefix in self._sync_want:
                        self._own_seen.add(prefix)
            else:
                self._remote_subscribed(prefix)
        if not events and timeout > 0.002:
            with self._remote_cond:
                self._remote_cond.wait(min(timeout, 0.01) - 0.002)

    def _sync(self, timeout: float) -> bool:
        n = next(_SYNC_IDS)
        base = b"%ssync/%d_%d" % (_OWN_TOPICS, os.getpid(), n)
        with self._rx_lock:
            lanes = list(self._lane_prefixes)
        marks = {lane: base + b"/%d\0" % i for i, lane in enumerate(lanes)}
        want = {base + b"\0", *marks.values()}
        with self._remote_cond:
            self._sync_want |= want
        probe = self._open_lane([base + b"\0"])  # for this endpoint's publish socket
        for lane, mark in marks.items():
            self._lane_op(zmq.SUBSCRIBE, mark, lane)
        try:
            deadline = time.monotonic() + timeout
            while not (self._closed or stopping()):
                with self._remote_cond:
                    if want <= self._own_seen:
                        return True
                if time.monotonic() >= deadline:
                    break
                self._service(_SYNC_POLL_S)
            return False
        finally:
            probe.close(0)
            if not self._closed:
                for lane, mark in marks.items():
                    self._lane_op(zmq.UNSUBSCRIBE, mark, lane)
            with self._remote_cond:
                self._own_seen -= want
                self._sync_want -= want

    # -- receiving --------------------------------------------------------------------------
    def _open_lane(self, prefixes: list[bytes]) -> zmq.Socket[bytes]:
        sock = self._ctx.socket(zmq.SUB)
        try:
            sock.linger = 0
            sock.rcvhwm = self.endpoints.hwm
            _apply_curve(sock, self._curve)
            sock.connect(self.endpoints.sub)
            for prefix in prefixes:
                sock.setsockopt(zmq.SUBSCRIBE, prefix)
        except zmq.ZMQError as exc:
            sock.close(0)
            raise ValueError(f"cannot connect to {self.endpoints.sub!r}: {exc.strerror}") from None
        return sock

    def _close_lane(self, lane: bytes) -> None:
        sock = self._lanes.pop(lane)
        self._poller.unregister(sock)
        if sock in self._rotation:
            self._rotation.remove(sock)
        sock.close(0)

    def _apply_pending(self) -> None:
        pending, self._pending = self._pending, []
        for op, prefix, lane in pending:
            prefixes = self._lane_prefixes.setdefault(lane, [])
            if op == zmq.SUBSCRIBE:
                prefixes.append(prefix)
                sock = self._lanes.get(lane)
                if sock is not None:
                    sock.setsockopt(zmq.SUBSCRIBE, prefix)
                    continue
            elif op == zmq.UNSUBSCRIBE:
                if prefix not in prefixes:  # a sync mark of a lane that went meanwhile
                    continue
                prefixes.remove(prefix)
                if prefixes:
                    self._lanes[lane].setsockopt(zmq.UNSUBSCRIBE, prefix)
                    continue
                del self._lane_prefixes[lane]
                self._close_lane(lane)
                continue
            elif lane in self._lanes:  # reset: the old socket and every queue behind it go
                self._close_lane(lane)
            if prefixes:
                sock = self._lanes[lane] = self._open_lane(prefixes)
                self._poller.register(sock, zmq.POLLIN)

    def _subscribe(self, prefix: bytes) -> None:
        self._queue_op(zmq.SUBSCRIBE, prefix)

    def _unsubscribe(self, prefix: bytes) -> None:
        self._queue_op(zmq.UNSUBSCRIBE, prefix)

    def _reset(self, prefix: bytes) -> None:
        self._queue_op(_RESET, prefix)

    def _queue_op(self, op: int, prefix: bytes) -> None:
        self._lane_op(op, prefix, self._lane_of[prefix])

    def _lane_op(self, op: int, prefix: bytes, lane: bytes) -> None:
        with self._rx_lock:
            self._pending.append((op, prefix, lane))
            if self._in_recv:
                self._poke()
            else:
                self._apply_pending()

    def _poke(self) -> None:
        try:
            self._wake_tx.send(b"", zmq.NOBLOCK)
        except zmq.Again:
            pass  # a wake is already queued; one is enough

    def _wakeup(self) -> None:
        with self._rx_lock:
            self._wake_flag = True
            if self._in_recv:
                self._poke()

    def _admit(self, ready: dict[zmq.Socket[bytes], int]) -> None:
        """Put lanes the poller found readable at the back of the rotation."""
        rotation = self._rotation
        for sock in ready:
            if sock is not self._wake_rx and sock not in rotation:
                rotation.append(sock)
        self._since_poll = 0

    def _next_queued(self) -> Frames | None:
        """One message from the next lane in turn (no waiting), or None if all are drained.

        While one lane keeps yielding (a flood), the others are polled again after a round of
        the rotation (at least every ``_POLL_EVERY`` messages), so a lane that just became
        readable waits for at most one message of each busy lane."""
        rotation = self._rotation
        if self._since_poll >= max(len(rotation), _POLL_EVERY):
            self._admit(dict(self._poller.poll(0)))
        while rotation:
            sock = rotation.popleft()
            # a lane found empty leaves the rotation: asked, not tried (a failed non-blocking
            # receive raises, which costs more than the question)
            if not cast(int, sock.getsockopt(zmq.EVENTS)) & zmq.POLLIN:
                continue
            frame = sock.recv(zmq.NOBLOCK, copy=False)
            # frame by frame without copy: cheaper than recv_multipart's option lookups
            frames = [frame.bytes]
            while frame.more:
                frame = sock.recv(zmq.NOBLOCK, copy=False)
                frames.append(frame.bytes)
            rotation.append(sock)
            self._since_poll += 1
            return frames
        return None

    def _recv_internal(self, timeout: float | None) -> Frames | None:
        with self._rx_lock:
            if self._wake_flag or self._closed:
                self._wake_flag = False
                return None
            self._in_recv = True
            if self._pending:
                self._apply_pending()
        try:
            frames = self._next_queued()
            if frames is not None:
                return frames
            deadline = None if timeout is None else time.monotonic() + timeout
            while True:
                wait_ms = None
                if deadline is not None:
                    wait_ms = max(0, math.ceil((deadline - time.monotonic()) * 1000))
                ready = dict(self._poller.poll(wait_ms))
                if self._wake_rx in ready:
                    while self._wake_rx.poll(0):
                        self._wake_rx.recv(zmq.NOBLOCK)
                    with self._rx_lock:
                        self._apply_pending()
                        if self._wake_flag or self._closed:
                            self._wake_flag = False
                            return None
                if not ready:
                    return None
                self._admit(ready)
                frames = self._next_queued()
                if frames is not None:
                    return frames
        finally:
            with self._rx_lock:
                self._in_recv = False
                if self._pending:
                    self._apply_pending()
                if self._closing:
                    self._rx_done.notify_all()

    def _close(self) -> None:
        with self._rx_lock:
            self._closing = True
            if self._in_recv:
                self._wake_flag = True
                self._poke()
                self._rx_done.wait_for(lambda: not self._in_recv, timeout=2.0)
            with self._pub_lock:
                self._pub.close(linger=PUB_LINGER_MS)
                for sock in (*self._lanes.values(), self._wake_rx, self._wake_tx):
                    sock.close(0)
                self._lanes.clear()
                self._rotation.clear()
