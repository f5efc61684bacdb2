"""``tcp://`` and ``ipc://``: the ZeroMQ bus through the XSUB/XPUB :class:`~hil_bridge.proxy.Proxy`.

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
A full queue drops (ZeroMQ HWM semantics) and never blocks the publisher; the receiving node
counts the loss from publisher ``seq`` gaps.

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
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import zmq
import zmq.auth

from hil_bridge.transport.base import Frames, Transport

#: how long messages queued on a closed publish socket are still delivered (milliseconds)
PUB_LINGER_MS = 1000

__all__ = ["ZmqEndpoints", "ZmqTransport", "parse_zmq_url"]

_WAKE_IDS = itertools.count()
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


def _apply_curve(sock: zmq.Socket, ends: ZmqEndpoints) -> None:
    if ends.curve_server is None or ends.curve_client is None:
        return
    server_public, _ = zmq.auth.load_certificate(Path(ends.curve_server))
    client_public, client_secret = zmq.auth.load_certificate(Path(ends.curve_client))
    if client_secret is None:
        raise ValueError(f"curve_client={ends.curve_client!r} holds no secret key (.key_secret)")
    sock.curve_serverkey = server_public
    sock.curve_publickey = client_public
    sock.curve_secretkey = client_secret


class ZmqTransport(Transport):
    """A bus endpoint on a ZeroMQ XSUB/XPUB proxy (see the module docstring)."""

    NEEDS_PROXY = True

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self.endpoints = ends = parse_zmq_url(url)
        ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
        self._pub_lock = threading.Lock()
        self._rx_lock = threading.Lock()
        self._rx_done = threading.Condition(self._rx_lock)
        self._in_recv = False
        self._wake_flag = False
        self._pending: list[tuple[int, bytes]] = []
        pub = ctx.socket(zmq.XPUB)
        sub = ctx.socket(zmq.SUB)
        wake_rx = ctx.socket(zmq.PAIR)
        wake_tx = ctx.socket(zmq.PAIR)
        self._sockets = (pub, sub, wake_rx, wake_tx)
        try:
            for sock in self._sockets:
                sock.linger = 0
            pub.setsockopt(zmq.XPUB_VERBOSE, 1)
            pub.sndhwm = ends.hwm
            sub.rcvhwm = ends.hwm
            _apply_curve(pub, ends)
            _apply_curve(sub, ends)
            wake = f"inproc://hil-bridge-wake-{next(_WAKE_IDS)}"
            wake_rx.bind(wake)
            wake_tx.connect(wake)
            for sock, endpoint in ((pub, ends.pub), (sub, ends.sub)):
                try:
                    sock.connect(endpoint)
                except zmq.ZMQError as exc:
                    raise ValueError(f"cannot connect to {endpoint!r}: {exc.strerror}") from None
        except (zmq.ZMQError, OSError, ValueError):
            for sock in self._sockets:
                sock.close(0)
            raise
        self._pub, self._sub, self._wake_rx, self._wake_tx = pub, sub, wake_rx, wake_tx
        self._poller = zmq.Poller()
        self._poller.register(sub, zmq.POLLIN)
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
            self._remote_subscribed(prefix)
        if not events and timeout > 0.002:
            with self._remote_cond:
                self._remote_cond.wait(min(timeout, 0.01) - 0.002)

    # -- receiving --------------------------------------------------------------------------
    def _apply_pending(self) -> None:
        for op, prefix in self._pending:
            self._sub.setsockopt(op, prefix)
        self._pending.clear()

    def _subscribe(self, prefix: bytes) -> None:
        self._queue_op(zmq.SUBSCRIBE, prefix)

    def _unsubscribe(self, prefix: bytes) -> None:
        self._queue_op(zmq.UNSUBSCRIBE, prefix)

    def _queue_op(self, op: int, prefix: bytes) -> None:
        with self._rx_lock:
            self._pending.append((op, prefix))
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

    def _recv_internal(self, timeout: float | None) -> Frames | None:
        with self._rx_lock:
            if self._wake_flag or self._closed:
                self._wake_flag = False
                return None
            self._in_recv = True
            self._apply_pending()
        try:
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
                if self._sub in ready:
                    return self._sub.recv_multipart(zmq.NOBLOCK)
                if not ready:
                    return None
        finally:
            with self._rx_lock:
                self._in_recv = False
                self._apply_pending()
                self._rx_done.notify_all()

    def _close(self) -> None:
        with self._rx_lock:
            if self._in_recv:
                self._wake_flag = True
                self._poke()
                self._rx_done.wait_for(lambda: not self._in_recv, timeout=2.0)
            with self._pub_lock:
                self._pub.close(linger=PUB_LINGER_MS)
                for sock in (self._sub, self._wake_rx, self._wake_tx):
                    sock.close(0)
