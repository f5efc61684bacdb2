"""A python-can bus from config that survives bus errors: :class:`CanLink`.

``CanBusConfig`` names the python-can interface, channel and bitrate, so the same code runs on
``virtual`` (in one process: tests), ``udp_multicast`` (across the processes of one host: the
launch's nodes; the domain's group and port, kept on loopback by
:class:`~drivers.can.loopback.LoopbackMulticastBus`),
``socketcan`` (``can0``/``vcan0``), ``pcan`` (``PCAN_USBBUS1``), ... with no code change;
``faults`` wraps the bus in :class:`drivers.faults.can_bus.FaultInjectingBus`. On every one of
them a link never receives the frames it sent (the loopback bus drops them in the kernel).

:class:`CanLink` contracts (one receive thread and one send thread may use it at once):

1. ``send(msg) -> bool`` never raises a bus error. "Send buffer full" (``ENOBUFS``/``EAGAIN``
   or any other transmit error) is retried up to ``send_retries`` times with exponential
   back-off from ``send_backoff_s``; a frame that still fails is dropped and counted.
2. Bus-off (``state == BusState.ERROR``, an error frame with ``CAN_ERR_BUSOFF``, or a transmit
   error ``ENETDOWN``) puts the link in ``bus_off``: frames are dropped (counted) without waiting;
   every back-off interval (``reopen_backoff_s`` doubling up to ``max_backoff_s``) one frame is
   tried, and if the bus still refuses it the bus is shut down, re-opened (a controller
   restart) and the frame tried once more. The first frame that goes through returns the link
   to ``up``.
3. ``recv(timeout)`` never raises a bus error: receive errors are counted and back off; error
   frames are counted (and steer the bus-off state) and never returned; ``reopen_after_failures``
   consecutive receive errors re-open the bus. A bus that cannot be opened leaves the link
   ``down`` and is retried with back-off.
4. With ``log_path`` every frame sent and received (error frames too) is written by python-can's
   ``can.Logger`` (``.log`` = candump ``-L`` format, readable by ``can.LogReader``), through a
   temporary file renamed at :meth:`CanLink.close`; an existing log is refused unless
   ``overwrite``. A link whose bus is refused for good (its constructor raises: an interface
   not usable here, a channel of the wrong kind) stops its logger and removes that file
   before it raises: a ``.db`` log's writer thread (python-can's, not a daemon) would keep
   the interpreter from ever exiting.
5. ``close()`` is idempotent and flushes the log.
6. :meth:`CanLink.report` says whether the bus was ever open and its state when closed (the run
   summary's ``links``, :func:`hil_bridge.launch.runner.collect_links`).
"""

from __future__ import annotations

import errno
import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np
from can import BusABC, BusState

from drivers.can.loopback import LoopbackMulticastBus
from drivers.faults.can_bus import (
    CAN_ERR_BUSOFF,
    CAN_ERR_RESTARTED,
    CanFaultConfig,
    FaultInjectingBus,
    fault_rngs,
)
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.outputs import AtomicOutput
from sim_core.config import from_dict

log = logging.getLogger(__name__)

__all__ = ["CanBusConfig", "CanLink", "LinkPolicy", "LinkState"]

LinkState = str  # "up" | "degraded" | "bus_off" | "down" | "closed"

_BUFFER_FULL = {errno.ENOBUFS, errno.EAGAIN}
_BUS_DOWN = {errno.ENETDOWN, errno.ENETUNREACH, errno.ENODEV}


@dataclass(frozen=True, slots=True)
class CanBusConfig:
    """Where the CAN bus is: python-can ``interface``, ``channel`` and ``bitrate``.

    :meth:`from_params` (what launch parameters go through) makes a ``virtual`` bus without a
    channel the domain's virtual CAN bus: in a numbered domain, whose nodes may be processes,
    the domain's ``udp_multicast`` group and port on loopback (:mod:`drivers.can.loopback`);
    in a private domain (one process) python-can's ``virtual`` channel ``glider.<token>``
    (:mod:`hil_bridge.bus.domain`), so two runs never share a bus by accident. A ``virtual`` bus
    with a channel is python-can's in-process one; other interfaces need a channel.
    ``bitrate`` None leaves the interface's own setting (socketcan takes it from
    ``ip link set can0 type can bitrate ...``). ``options`` are further ``can.Bus`` keyword
    arguments (e.g. ``{receive_own_messages: true}``). ``faults`` injects bus faults.
    """

    interface: str = "virtual"
    channel: str = ""
    bitrate: int | None = None
    options: dict[str, Any] = field(default_factory=dict)
    faults: CanFaultConfig | None = None

    def __post_init__(self) -> None:
        if self.interface not in can.interfaces.BACKENDS:
            raise ValueError(
                f"interface: unknown python-can interface {self.interface!r}; "
                f"expected one of {sorted(can.interfaces.BACKENDS)}"
            )
        if not self.channel:
            raise ValueError(f"channel: expected the {self.interface!r} channel to use, e.g. "
                             "can0 (socketcan) or PCAN_USBBUS1 (pcan)")
        if self.bitrate is not None and not 0 < self.bitrate <= 8_000_000:
            raise ValueError(f"bitrate: expected bits/s in (0, 8e6], got {self.bitrate}")

    @classmethod
    def from_params(
        cls,
        *,
        interface: str = "virtual",
        channel: str | int | None = None,
        bitrate: int | None = None,
        options: dict[str, Any] | None = None,
        faults: CanFaultConfig | dict[str, Any] | None = None,
    ) -> CanBusConfig:
        """Build from launch-style params (``faults`` may be a mapping of CanFaultConfig)."""
        if isinstance(faults, dict):
            faults = from_dict(CanFaultConfig, faults, path="faults")
        opts = dict(options or {})
        domain = current_domain()
        if interface == "virtual" and channel is None and domain.number is not None:
            interface = "udp_multicast"  # the domain's virtual bus crosses its processes
        if interface == "virtual" and channel is None:
            channel = domain.can_channel("glider")
        if interface == "udp_multicast":
            group, port = domain.can_multicast()
            channel = group if channel is None else channel
            opts.setdefault("port", port)
        return cls(
            interface=str(interface), channel="" if channel is None else str(channel),
            bitrate=bitrate, options=opts, faults=faults,
        )


@dataclass(frozen=True, slots=True)
class LinkPolicy:
    """Retry and back-off tunables of :class:`CanLink` (seconds)."""

    send_timeout_s: float = 0.005
    send_retries: int = 3
    send_backoff_s: float = 0.0005
    reopen_backoff_s: float = 0.05
    max_backoff_s: float = 2.0
    reopen_after_failures: int = 10

    def __post_init__(self) -> None:
        for name in ("send_timeout_s", "send_backoff_s", "reopen_backoff_s", "max_backoff_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 s, got {getattr(self, name)}")
        if self.send_retries < 0:
            raise ValueError(f"send_retries must be >= 0, got {self.send_retries}")
        if self.reopen_after_failures < 1:
            raise ValueError(
                f"reopen_after_failures must be >= 1, got {self.reopen_after_failures}"
            )


class CanLink:
    """A resilient python-can bus (see the module docstring for the contracts)."""

    def __init__(
        self,
        config: CanBusConfig,
        *,
        policy: LinkPolicy | None = None,
        log_path: str | Path | None = None,
        stop_event: threading.Event | None = None,
        overwrite: bool = False,
    ) -> None:
        self.config = config
        self.policy = policy if policy is not None else LinkPolicy()
        self._stop = stop_event if stop_event is not None else threading.Event()
        self._lock = threading.RLock()
        self._log_lock = threading.Lock()
        self._count_lock = threading.Lock()
        self._bus: BusABC | None = None
        self._rngs: tuple[np.random.Generator, np.random.Generator] | None = (
            fault_rngs(config.faults.seed) if config.faults is not None else None
        )
        self._state: LinkState = "down"
        self._open_warned = False  # one warning per outage, not one per retry
        self._bus_off_since = 0.0
        self._next_probe = 0.0
        self._probe_backoff = self.policy.reopen_backoff_s
        self._next_open = 0.0
        self._open_backoff = self.policy.reopen_backoff_s
        self._rx_fail = 0
        self._tx_fail = 0
        self._closed = False
        self._ever_open = False
        self._final_state: LinkState = "down"
        self.last_error = ""
        self.counters: Counter[str] = Counter()
        self._logger: can.Listener | None = None
        self._log_output: AtomicOutput | None = None
        if log_path is not None:
            out = self._log_output = AtomicOutput(log_path, overwrite=overwrite)
            kwargs: dict[str, Any] = {}
            if out.path.suffix == ".log":
                kwargs["channel"] = str(config.channel)
            try:
                self._logger = can.Logger(out.tmp, **kwargs)
            except BaseException:
                out.discard()
                raise
        try:
            self._try_open(first=True)
        except BaseException:  # a bus refused for good: the log it would have fed goes too
            self._drop_log()
            raise

    # -- state --------------------------------------------------------------------------------
    @property
    def state(self) -> LinkState:
        return self._state

    @property
    def bus(self) -> BusABC | None:
        """The current python-can bus (replaced on re-open); None while down."""
        return self._bus

    def _inc(self, name: str, n: int = 1) -> None:
        with self._count_lock:
            self.counters[name] += n

    def stats(self) -> dict[str, Any]:
        """Counters (ints) plus ``state`` (str)."""
        with self._count_lock:
            out: dict[str, Any] = dict(self.counters)
        out["state"] = self._state
        return out

    def report(self) -> dict[str, Any]:
        """``{"kind": "can", "target": "interface:channel", "connected" (ever open), "state"
        (now, or when closed), "reconnects", "error" (the last open error)}``."""
        return {
            "kind": "can", "target": f"{self.config.interface}:{self.config.channel}",
            "connected": self._ever_open,
            "state": self._final_state if self._closed else self._state,
            "reconnects": self.counters.get("reopens", 0), "error": self.last_error,
        }

    # -- open / re-open -----------------------------------------------------------------------
    def _make_bus(self) -> BusABC:
        cfg = self.config
        kwargs: dict[str, Any] = dict(cfg.options)
        if cfg.bitrate is not None:
            kwargs["bitrate"] = cfg.bitrate
        bus: BusABC
        if cfg.interface == "udp_multicast":
            kwargs.pop("hop_limit", None)
            bus = LoopbackMulticastBus(cfg.channel, **kwargs)
        else:
            bus = can.Bus(interface=cfg.interface, channel=cfg.channel, **kwargs)
        if cfg.faults is not None:
            bus = FaultInjectingBus(bus, cfg.faults, rngs=self._rngs)
        return bus

    def _try_open(self, *, first: bool = False) -> bool:
        with self._lock:
            if self._closed:
                return False
            try:
                bus = self._make_bus()
            except (can.CanError, OSError) as exc:
                if isinstance(exc, can.CanInterfaceNotImplementedError):
                    raise ValueError(
                        f"interface {self.config.interface!r} is not usable here: {exc}"
                    ) from None
                self._inc("open_failures")
                self.last_error = f"{type(exc).__name__}: {exc}"
                if not self._open_warned:
                    self._open_warned = True
                    log.warning("CAN %s:%s cannot be opened (%s); retrying with back-off",
                                self.config.interface, self.config.channel, exc)
                self._state = "down"
                self._next_open = time.monotonic() + self._open_backoff
                self._open_backoff = min(2 * self._open_backoff, self.policy.max_backoff_s)
                return False
            self._bus = bus
            self._ever_open = True
            self._open_warned = False
            if self._state != "bus_off":
                self._state = "up"
            self._open_backoff = self.policy.reopen_backoff_s
            self._rx_fail = self._tx_fail = 0
            if not first:
                self._inc("reopens")
            return True

    def _reopen(self) -> bool:
        with self._lock:
            old, self._bus = self._bus, None
            if old is not None:
                try:
                    old.shutdown()
                except (can.CanError, OSError):
                    self._inc("shutdown_errors")
            return self._try_open()

    def _ensure_open(self) -> BusABC | None:
        bus = self._bus
        if bus is not None:
            return bus
        with self._lock:
            if self._bus is None and time.monotonic() >= self._next_open:
                self._try_open()
            return self._bus

    # -- bus-off ------------------------------------------------------------------------------
    def _enter_bus_off(self) -> None:
        with self._lock:
            if self._state != "bus_off":
                self._inc("bus_off")
                self._state = "bus_off"
                self._bus_off_since = time.monotonic()
                self._probe_backoff = self.policy.reopen_backoff_s
                self._next_probe = self._bus_off_since + self._probe_backoff

    def _leave_bus_off(self) -> None:
        with self._lock:
            if self._state == "bus_off":
                self._inc("bus_off_recoveries")
                self._inc("bus_off_ms", int(1000 * (time.monotonic() - self._bus_off_since)))
                self._state = "up"

    # -- send ---------------------------------------------------------------------------------
    def send(self, msg: can.Message) -> bool:
        """Send ``msg``; True if the bus took it (see contract 1–2). Never raises a bus error."""
        if self._closed:
            return False
        bus = self._ensure_open()
        if bus is None:
            self._inc("tx_dropped_down")
            return False
        if self._state == "bus_off" or bus.state == BusState.ERROR:
            self._enter_bus_off()
            now = time.monotonic()
            if now < self._next_probe:
                self._inc("tx_dropped_bus_off")
                return False
            self._probe_backoff = min(2 * self._probe_backoff, self.policy.max_backoff_s)
            self._next_probe = now + self._probe_backoff
            if bus.state == BusState.ERROR or not self._try_send_once(bus, msg):
                fresh = self._bus if self._reopen() else None
                if fresh is None or fresh.state == BusState.ERROR or not self._try_send_once(
                    fresh, msg
                ):
                    self._inc("tx_dropped_bus_off")
                    return False
            self._leave_bus_off()
            self._sent(msg)
            return True
        backoff = self.policy.send_backoff_s
        for attempt in range(self.policy.send_retries + 1):
            try:
                bus.send(msg, timeout=self.policy.send_timeout_s)
            except can.CanOperationError as exc:
                code = exc.error_code
                if code in _BUS_DOWN:
                    self._enter_bus_off()
                    self._inc("tx_dropped_bus_off")
                    return False
                self._inc("tx_buffer_full" if code in _BUFFER_FULL else "tx_errors")
            except (can.CanError, OSError):
                self._inc("tx_errors")
            else:
                self._tx_fail = 0
                if attempt:
                    self._inc("tx_retried_ok")
                if self._state == "degraded":
                    self._state = "up"
                self._sent(msg)
                return True
            if attempt < self.policy.send_retries and self._stop.wait(backoff):
                break
            backoff *= 2
        self._inc("tx_dropped")
        self._tx_fail += 1
        self._state = "degraded"
        if self._tx_fail >= self.policy.reopen_after_failures:
            self._reopen()
        return False

    def _try_send_once(self, bus: BusABC, msg: can.Message) -> bool:
        try:
            bus.send(msg, timeout=self.policy.send_timeout_s)
        except (can.CanError, OSError):
            return False
        return True

    def _sent(self, msg: can.Message) -> None:
        self._inc("tx_frames")
        if self._logger is not None:
            msg.timestamp = time.time()
            msg.is_rx = False
            self._log(msg)

    def _log(self, msg: can.Message) -> None:
        with self._log_lock:
            if self._logger is not None:
                self._logger.on_message_received(msg)

    # -- receive ------------------------------------------------------------------------------
    def recv(self, timeout: float) -> can.Message | None:
        """The next data frame, or None after ``timeout`` s (contract 3). Never raises."""
        deadline = time.monotonic() + timeout
        while not self._closed:
            left = deadline - time.monotonic()
            if left < 0:
                return None
            msg = self._recv_once(left)
            if msg is not None:
                return msg
        return None

    def _recv_once(self, timeout: float) -> can.Message | None:
        bus = self._ensure_open()
        if bus is None:
            self._stop.wait(min(timeout, max(0.0, self._next_open - time.monotonic())))
            return None
        try:
            msg = bus.recv(timeout)
        except (can.CanError, OSError, ValueError):
            if bus is not self._bus or self._closed:
                return None
            self._inc("rx_errors")
            self._rx_fail += 1
            if self._rx_fail >= self.policy.reopen_after_failures:
                self._reopen()
            else:
                self._stop.wait(
                    min(timeout, self.policy.max_backoff_s,
                        self.policy.send_backoff_s * 2**self._rx_fail)
                )
            return None
        self._rx_fail = 0
        if msg is None:
            return None
        self._log(msg)
        if msg.is_error_frame:
            self._inc("error_frames")
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self._enter_bus_off()
            elif msg.arbitration_id & CAN_ERR_RESTARTED:
                self._leave_bus_off()
            return None
        self._inc("rx_frames")
        return msg

    # -- close --------------------------------------------------------------------------------
    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._final_state = self._state
            self._state = "closed"
            bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError):
                self._inc("shutdown_errors")
        with self._log_lock:
            if self._logger is not None:
                self._logger.stop()
                self._logger = None
            if self._log_output is not None:
                self._log_output.commit()

    def _drop_log(self) -> None:
        """Stop the logger (its writer thread, for a ``.db`` log) and remove its temporary
        file: nothing of a link that never was outlives its constructor."""
        with self._log_lock:
            if self._logger is not None:
                self._logger.stop()
                self._logger = None
            if self._log_output is not None:
                self._log_output.discard()

    def __enter__(self) -> CanLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
