"""Fault-injecting python-can bus: wraps any :class:`can.BusABC` (no root, no vcan needed).

Injected faults, each drawn from a seeded generator (one stream per direction, so a given
sequence of sends, or of receives, meets the same faults for the same seed):

* **error frames** — an error frame (``is_error_frame``, socketcan class bits in the id, e.g.
  ``CAN_ERR_PROT``) is delivered before a received frame;
* **truncated frames** — a received frame arrives with fewer than its data bytes;
* **foreign frames** — a frame with an id outside the profile (another device's traffic);
* **dropped frames** — a received frame is lost;
* **send buffer full** — ``send`` raises ``can.CanOperationError`` with
  ``error_code == errno.ENOBUFS`` (as socketcan does when the qdisc/driver queue is full), for
  ``enobufs_burst`` consecutive sends;
* **bus-off** — the controller goes bus-off: ``state`` becomes ``BusState.ERROR``, ``send`` raises
  ``CanOperationError`` (``errno.ENETDOWN``), received traffic is lost, and one error frame with
  ``CAN_ERR_BUSOFF`` is delivered. It recovers by itself after ``bus_off_s`` (as socketcan's
  ``restart-ms``), delivering an error frame with ``CAN_ERR_RESTARTED``; re-opening the bus
  (a fresh wrapper around a fresh bus) recovers at once, as ``ip link set canX type can restart``;
* **receive errors** — ``recv`` raises ``CanOperationError`` (``errno.EIO``);
* **delays** — received frames are held back by ``U(0, delay_s)`` seconds, keeping their order.

Faults can also be triggered deterministically (``inject_bus_off``, ``inject_enobufs``) for tests.
"""

from __future__ import annotations

import collections
import errno
import threading
import time
from dataclasses import dataclass
from typing import Any

import can
import numpy as np
from can import BusABC, BusState

from sim_core.rng import derive_rng

__all__ = [
    "CAN_ERR_BUSOFF",
    "CAN_ERR_CRTL",
    "CAN_ERR_PROT",
    "CAN_ERR_RESTARTED",
    "CanFaultConfig",
    "FaultInjectingBus",
    "fault_rngs",
]

#: socketcan error classes (linux/can/error.h), carried in an error frame's arbitration id.
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_BUSOFF = 0x040
CAN_ERR_RESTARTED = 0x100

_FOREIGN_IDS = (0x700, 0x7FF)  # outside every profile base id (0x100..0x16F)


@dataclass(frozen=True, slots=True)
class CanFaultConfig:
    """Fault probabilities (per frame or per call) and durations; all zero = transparent."""

    seed: int = 0
    error_frame_rate: float = 0.0
    truncate_rate: float = 0.0
    foreign_rate: float = 0.0
    drop_rate: float = 0.0
    enobufs_rate: float = 0.0
    enobufs_burst: int = 3
    bus_off_rate: float = 0.0
    bus_off_s: float = 0.2
    recv_error_rate: float = 0.0
    delay_s: float = 0.0

    def __post_init__(self) -> None:
        for name in (
            "error_frame_rate", "truncate_rate", "foreign_rate", "drop_rate",
            "enobufs_rate", "bus_off_rate", "recv_error_rate",
        ):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], got {value}")
        if self.enobufs_burst < 1:
            raise ValueError(f"enobufs_burst must be >= 1, got {self.enobufs_burst}")
        if not self.bus_off_s >= 0.0:
            raise ValueError(f"bus_off_s must be >= 0 s, got {self.bus_off_s}")
        if not self.delay_s >= 0.0:
            raise ValueError(f"delay_s must be >= 0 s, got {self.delay_s}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")


def fault_rngs(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """The (send, receive) generators of ``seed``; keep them across re-opens of the bus."""
    return derive_rng(seed, "can_faults", "tx"), derive_rng(seed, "can_faults", "rx")


class FaultInjectingBus(BusABC):
    """A python-can bus that forwards to ``inner`` and injects the faults of ``config``.

    ``rngs`` = (send, receive) generators; by default :func:`fault_rngs` of ``config.seed``.
    ``shutdown`` also shuts ``inner`` down. ``injected`` holds the counts of injected faults.
    """

    def __init__(
        self,
        inner: BusABC,
        config: CanFaultConfig | None = None,
        *,
        rngs: tuple[np.random.Generator, np.random.Generator] | None = None,
        **kwargs: Any,
    ) -> None:
        self.inner = inner
        self.config = config if config is not None else CanFaultConfig()
        self._tx_rng, self._rx_rng = rngs if rngs is not None else fault_rngs(self.config.seed)
        self._lock = threading.Lock()
        self._bus_off_until: float | None = None
        self._bus_off_announced = False
        self._restart_pending = False
        self._enobufs_left = 0
        self._held: collections.deque[tuple[float, can.Message]] = collections.deque()
        self._pending_error: can.Message | None = None
        self.injected: dict[str, int] = collections.Counter()
        self.channel_info = f"faults({inner.channel_info})"
        super().__init__(channel=inner.channel_info, **kwargs)

    # -- deterministic triggers ---------------------------------------------------------------
    def inject_bus_off(self, duration_s: float | None = None) -> None:
        """Go bus-off now for ``duration_s`` (default ``config.bus_off_s``)."""
        with self._lock:
            self._enter_bus_off(self.config.bus_off_s if duration_s is None else duration_s)

    def inject_enobufs(self, count: int) -> None:
        """Make exactly the next ``count`` sends fail with ENOBUFS (0 clears a pending burst)."""
        if count < 0:
            raise ValueError(f"count must be >= 0, got {count}")
        with self._lock:
            self._enobufs_left = int(count)

    def _enter_bus_off(self, duration_s: float) -> None:
        self._bus_off_until = time.monotonic() + duration_s
        self._bus_off_announced = False
        self._held.clear()
        self.injected["bus_off"] += 1

    def _bus_off_now(self) -> bool:
        """True while bus-off; performs the automatic restart when its time has come."""
        if self._bus_off_until is None:
            return False
        if time.monotonic() >= self._bus_off_until:
            self._bus_off_until = None
            self._restart_pending = True
            while self.inner.recv(0.0) is not None:
                self.injected["lost_bus_off"] += 1
            return False
        return True

    @property
    def state(self) -> BusState:
        with self._lock:
            return BusState.ERROR if self._bus_off_now() else self.inner.state

    @state.setter
    def state(self, new_state: BusState) -> None:
        self.inner.state = new_state

    # -- send ---------------------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        cfg = self.config
        with self._lock:
            if self._bus_off_now():
                raise can.CanOperationError("bus-off: transmit refused", error_code=errno.ENETDOWN)
            if cfg.bus_off_rate and self._tx_rng.random() < cfg.bus_off_rate:
                self._enter_bus_off(cfg.bus_off_s)
                raise can.CanOperationError("bus-off: transmit refused", error_code=errno.ENETDOWN)
            if self._enobufs_left == 0 and cfg.enobufs_rate:
                if self._tx_rng.random() < cfg.enobufs_rate:
                    self._enobufs_left = cfg.enobufs_burst
            if self._enobufs_left > 0:
                self._enobufs_left -= 1
                self.injected["enobufs"] += 1
                raise can.CanOperationError(
                    "Failed to transmit: No buffer space available", error_code=errno.ENOBUFS
                )
        self.inner.send(msg, timeout)

    # -- receive ------------------------------------------------------------------------------
    def _error_frame(self, err_class: int) -> can.Message:
        return can.Message(
            timestamp=time.time(), arbitration_id=err_class, is_error_frame=True,
            is_extended_id=False, dlc=8, data=bytes(8),
        )

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        cfg = self.config
        with self._lock:
            if self._bus_off_now():
                if not self._bus_off_announced:
                    self._bus_off_announced = True
                    return self._error_frame(CAN_ERR_BUSOFF), False
                wait = max(0.0, (self._bus_off_until or 0.0) - time.monotonic())
            else:
                wait = None
                if self._restart_pending:
                    self._restart_pending = False
                    return self._error_frame(CAN_ERR_RESTARTED), False
                if self._pending_error is not None:
                    msg, self._pending_error = self._pending_error, None
                    return msg, False
                if self._held and self._held[0][0] <= time.monotonic():
                    return self._held.popleft()[1], False
                if cfg.recv_error_rate and self._rx_rng.random() < cfg.recv_error_rate:
                    self.injected["recv_errors"] += 1
                    raise can.CanOperationError("Error receiving: I/O error", error_code=errno.EIO)
        if wait is not None:
            # Bus-off: the controller hears nothing; discard what the inner bus receives.
            self._discard_inner(min(wait, timeout) if timeout is not None else wait)
            return None, False
        if self._held:
            due = self._held[0][0] - time.monotonic()
            timeout = max(0.0, due) if timeout is None else max(0.0, min(timeout, due))
        received = self.inner.recv(timeout)
        if received is None:
            return None, False
        return self._mangle(received), False

    def _discard_inner(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or self.inner.recv(left) is None:
                return
            self.injected["lost_bus_off"] += 1

    def _mangle(self, msg: can.Message) -> can.Message | None:
        cfg = self.config
        rng = self._rx_rng
        with self._lock:
            if self._bus_off_now():
                return None
            if cfg.drop_rate and rng.random() < cfg.drop_rate:
                self.injected["dropped"] += 1
                return None
            if cfg.truncate_rate and rng.random() < cfg.truncate_rate and msg.dlc > 0:
                n = int(rng.integers(0, msg.dlc))
                msg = can.Message(
                    timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                    is_extended_id=msg.is_extended_id, dlc=n, data=bytes(msg.data[:n]),
                )
                self.injected["truncated"] += 1
            if cfg.foreign_rate and rng.random() < cfg.foreign_rate:
                msg = can.Message(
                    timestamp=msg.timestamp,
                    arbitration_id=int(rng.integers(_FOREIGN_IDS[0], _FOREIGN_IDS[1] + 1)),
                    is_extended_id=False, dlc=8, data=rng.bytes(8),
                )
                self.injected["foreign"] += 1
            if cfg.error_frame_rate and rng.random() < cfg.error_frame_rate:
                self.injected["error_frames"] += 1
                self._pending_error = msg
                return self._error_frame(CAN_ERR_PROT)
            if cfg.delay_s:
                self._held.append((time.monotonic() + float(rng.uniform(0.0, cfg.delay_s)), msg))
                self.injected["delayed"] += 1
                return None
            return msg

    def shutdown(self) -> None:
        if not self._is_shutdown:
            self.inner.shutdown()
        super().shutdown()
