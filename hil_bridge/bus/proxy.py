"""The bus proxy: ZeroMQ XSUB (publish endpoint) ↔ XPUB (subscribe endpoint) in a thread.

Messages are forwarded by libzmq's own ``zmq_proxy_steerable`` (no Python per message, no GIL).
The XPUB side is verbose, so every subscription reaches every publisher, even duplicates; that is
what lets publishers wait for their subscribers and re-send latched values (see
:mod:`hil_bridge.bus.transport.zmq`). Queues are bounded by ``hwm`` and drop, never block.

Binding is loopback-only unless CURVE keys are given (:func:`hil_bridge.bus.security.check_bind`).
A port ``0`` binds an ephemeral port; :attr:`Proxy.url` is then the bus URL clients use.
``realtime`` (a launch of real-time nodes gives their highest priority) runs the forwarder and
its I/O threads under ``SCHED_FIFO`` at that priority (:mod:`hil_bridge.priority`): every
message's path crosses them.
"""

from __future__ import annotations

import itertools
import threading
from types import TracebackType

import zmq
from zmq.auth.thread import ThreadAuthenticator

from hil_bridge.bus.security import CurveKeys, KeyAllowList, check_bind
from hil_bridge.bus.transport import backend_class
from hil_bridge.bus.transport.zmq import parse_zmq_url
from hil_bridge.priority import realtime, realtime_io

__all__ = ["Proxy", "proxy_for"]

_IDS = itertools.count()


def _bindable(endpoint: str) -> str:
    if endpoint.startswith("tcp://") and endpoint.endswith(":0"):
        return endpoint[:-2] + ":*"
    return endpoint


class Proxy:
    """XSUB/XPUB forwarder: ``Proxy(pub_endpoint, sub_endpoint, *, curve=None, hwm=1000)``;
    endpoints left out are the current domain's bus (:mod:`hil_bridge.bus.domain`).

    ``start()`` binds (raising at once on a bad or busy endpoint or a security refusal) and
    runs the forwarder thread; ``stop()`` ends it and closes every socket. Both are idempotent;
    ``with Proxy(...) as p:`` starts and stops.
    """

    def __init__(
        self,
        pub_endpoint: str | None = None,
        sub_endpoint: str | None = None,
        *,
        curve: CurveKeys | None = None,
        hwm: int = 1000,
        realtime: int = 0,
    ) -> None:
        if pub_endpoint is None or sub_endpoint is None:
            from hil_bridge.bus.domain import current

            ends = parse_zmq_url(current().bus_url)
            pub_endpoint = ends.pub if pub_endpoint is None else pub_endpoint
            sub_endpoint = ends.sub if sub_endpoint is None else sub_endpoint
        check_bind([pub_endpoint, sub_endpoint], curve)
        if hwm < 1:
            raise ValueError(f"hwm must be >= 1, got {hwm}")
        self._requested = (pub_endpoint, sub_endpoint)
        self.curve = curve
        self.hwm = hwm
        self.realtime = realtime
        self.allow_list = KeyAllowList(curve.allowed) if curve is not None else None
        self.pub_endpoint = pub_endpoint
        self.sub_endpoint = sub_endpoint
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._ctx: zmq.Context | None = None
        self._ctrl: zmq.Socket | None = None
        self._auth: ThreadAuthenticator | None = None
        self.error: BaseException | None = None

    @classmethod
    def from_url(cls, url: str, *, curve: CurveKeys | None = None, hwm: int = 1000,
                 realtime: int = 0) -> Proxy:
        """The proxy serving the ZeroMQ bus URL ``url`` (same endpoint rules as the clients)."""
        ends = parse_zmq_url(url)
        return cls(ends.pub, ends.sub, curve=curve, hwm=hwm, realtime=realtime)

    @property
    def url(self) -> str:
        """The bus URL clients pass to ``open_transport`` / ``Node(bus=...)``."""
        return f"{self.pub_endpoint}?sub={self.sub_endpoint}"

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> Proxy:
        with self._lock:
            if self._thread is not None:
                return self
            ctx = zmq.Context()
            if self.realtime:
                realtime_io(self.realtime, ctx)
            sockets: list[zmq.Socket] = []
            auth: ThreadAuthenticator | None = None
            try:
                if self.curve is not None and self.allow_list is not None:
                    auth = ThreadAuthenticator(ctx)
                    auth.start()
                    auth.configure_curve_callback("*", credentials_provider=self.allow_list)
                xsub = ctx.socket(zmq.XSUB)
                xpub = ctx.socket(zmq.XPUB)
                ctrl_tx = ctx.socket(zmq.PAIR)
                ctrl_rx = ctx.socket(zmq.PAIR)
                sockets = [xsub, xpub, ctrl_tx, ctrl_rx]
                for sock in sockets:
                    sock.linger = 0
                xpub.setsockopt(zmq.XPUB_VERBOSE, 1)
                xsub.rcvhwm = self.hwm
                xpub.sndhwm = self.hwm
                if self.curve is not None:
                    for sock in (xsub, xpub):
                        sock.curve_secretkey = self.curve.server_secret
                        sock.curve_publickey = self.curve.server_public
                        sock.curve_server = True
                for sock, endpoint in ((xsub, self._requested[0]), (xpub, self._requested[1])):
                    try:
                        sock.bind(_bindable(endpoint))
                    except zmq.ZMQError as exc:
                        raise OSError(
                            exc.errno, f"cannot bind {endpoint}: {exc.strerror}"
                        ) from None
                ctrl = f"inproc://hil-bridge-proxy-ctrl-{next(_IDS)}"
                ctrl_rx.bind(ctrl)
                ctrl_tx.connect(ctrl)
            except BaseException:
                for sock in sockets:
                    sock.close(0)
                if auth is not None:
                    auth.stop()
                ctx.term()
                raise
            self.pub_endpoint = xsub.getsockopt_string(zmq.LAST_ENDPOINT)
            self.sub_endpoint = xpub.getsockopt_string(zmq.LAST_ENDPOINT)
            self._ctx, self._ctrl, self._auth = ctx, ctrl_tx, auth
            self._thread = threading.Thread(
                target=self._run, args=(xsub, xpub, ctrl_rx), name="hil-bridge-proxy", daemon=True
            )
            self._thread.start()
            return self

    def _run(self, xsub: zmq.Socket, xpub: zmq.Socket, ctrl: zmq.Socket) -> None:
        if self.realtime:
            realtime(self.realtime)
        try:
            zmq.proxy_steerable(xsub, xpub, None, ctrl)
        except zmq.ZMQError as exc:
            if exc.errno != zmq.ETERM:
                self.error = exc
        finally:
            for sock in (xsub, xpub, ctrl):
                sock.close(0)

    def stop(self) -> None:
        with self._lock:
            thread, self._thread = self._thread, None
            if thread is None:
                return
            ctx, ctrl, auth = self._ctx, self._ctrl, self._auth
            self._ctx = self._ctrl = self._auth = None
            if ctrl is not None:
                ctrl.send(b"TERMINATE")
            thread.join()
            if ctrl is not None:
                ctrl.close(0)
            if auth is not None:
                auth.stop()
            if ctx is not None:
                ctx.term()

    def stats(self) -> dict[str, int]:
        """Authentication counters (``auth_accepted``, ``auth_rejected``) when CURVE is on."""
        return self.allow_list.stats() if self.allow_list is not None else {}

    def __enter__(self) -> Proxy:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


def proxy_for(url: str, *, curve: CurveKeys | None = None, hwm: int = 1000,
              realtime: int = 0) -> Proxy | None:
    """The (unstarted) proxy a bus URL needs, or ``None`` for in-process buses (``mem://``)."""
    if not backend_class(url).NEEDS_PROXY:
        return None
    return Proxy.from_url(url, curve=curve, hwm=hwm, realtime=realtime)
