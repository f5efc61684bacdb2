"""A protocol double of ArduPilot SITL's JSON backend, written from its contract, for tests and
benchmarks where no firmware runs (``docs/ardupilot.md``).

:class:`SitlDouble` is SITL's side of the wire: it sends servo packets (``<HHI16H``, magic
18458, or 32 channels, magic 29569) to a node's UDP port with a rising frame counter and
reads each answer as SITL does: the text between the last two newlines, parsed as JSON. It
checks what SITL relies on and raises :class:`ContractError` otherwise: the mandatory fields
(``timestamp``, ``imu.gyro``, ``imu.accel_body``, ``position``, ``quaternion`` or
``attitude``, ``velocity``), their order, finite numbers only (a NaN is refused), and a
timestamp that never goes back. In lockstep (the default) each frame waits for its answer.

Its pilot, :class:`WingLeveler`, is just enough to keep a glider flying: bank held by aileron,
airspeed by elevator about a trim (JSBSim's signs: positive elevator is nose down).
"""

from __future__ import annotations

import json
import math
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim_core.pose import euler_from_quat

__all__ = ["MANDATORY", "ContractError", "SitlDouble", "WingLeveler"]

#: the fields SITL cannot fly without, in the order it expects them
MANDATORY = ("timestamp", "imu", "position", "quaternion", "velocity")


class ContractError(AssertionError):
    """An answer that breaks SITL's JSON contract."""


def _no_constants(name: str) -> float:
    raise ContractError(f"non-finite number {name} in a JSON answer")


@dataclass
class WingLeveler:
    """PWM (µs, 16 channels) from the last answer: aileron (channel 1) holds ``bank_deg``
    (ENU-free: roll about the FRD forward axis, positive right wing down), elevator (channel 2)
    holds ``airspeed_mps`` about ``trim`` (normalised, nose up negative)."""

    bank_deg: float = 0.0
    airspeed_mps: float = 19.5
    trim: float = -0.15
    k_roll: float = 1.5
    k_rate: float = 0.3
    k_speed: float = 0.03

    def __call__(self, fdm: dict[str, Any] | None) -> list[int]:
        pwm = [1500] * 16
        pwm[2] = 1000
        if fdm is None:
            pwm[1] = round(1500 + 500 * self.trim)
            return pwm
        w, x, y, z = fdm["quaternion"]
        roll, _, _ = euler_from_quat(np.array([w, x, y, z]))
        p = fdm["imu"]["gyro"][0]
        ail = -self.k_roll * (float(roll) - math.radians(self.bank_deg)) - self.k_rate * p
        speed = float(fdm.get("airspeed", self.airspeed_mps))
        ele = self.trim - self.k_speed * (speed - self.airspeed_mps)
        pwm[0] = round(1500 + 500 * min(max(ail, -1.0), 1.0))
        pwm[1] = round(1500 + 500 * min(max(ele, -1.0), 1.0))
        return pwm


@dataclass
class SitlDouble:
    """SITL's end of the JSON interface, sending to ``host:port``."""

    port: int
    host: str = "127.0.0.1"
    frame_rate: int = 400
    channels: int = 16
    timeout_s: float = 5.0
    frame_count: int = 0
    last: dict[str, Any] | None = None
    rtt_us: list[float] = field(default_factory=list)
    _sock: Any = None

    def __post_init__(self) -> None:
        if self.channels not in (16, 32):
            raise ValueError(f"channels: expected 16 or 32, got {self.channels}")
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((self.host, 0))
        self._sock.settimeout(self.timeout_s)

    def close(self) -> None:
        self._sock.close()

    def packet(self, pwm: list[int], frame_count: int | None = None) -> bytes:
        """A servo packet with ``pwm`` (padded with 0 to the channel count)."""
        magic = 18458 if self.channels == 16 else 29569
        vals = (list(pwm) + [0] * self.channels)[: self.channels]
        count = self.frame_count if frame_count is None else frame_count
        return struct.pack(f"<HHI{self.channels}H", magic, self.frame_rate, count, *vals)

    def send_raw(self, data: bytes) -> None:
        """Send any datagram (a bad packet, a repeat)."""
        self._sock.sendto(data, (self.host, self.port))

    def receive(self) -> dict[str, Any]:
        """The next answer, checked against the contract."""
        data, _ = self._sock.recvfrom(65536)
        return self.check(data)

    def check(self, data: bytes) -> dict[str, Any]:
        """Parse an answer as SITL does and check it (:class:`ContractError`)."""
        text = data.decode("ascii")
        parts = text.split("\n")
        if len(parts) < 3 or parts[-1] != "":
            raise ContractError(f"answer not framed by newlines: {text!r}")
        doc = json.loads(parts[-2], parse_constant=_no_constants)
        keys = list(doc)
        att = "quaternion" if "quaternion" in doc else "attitude"
        want = [att if k == "quaternion" else k for k in MANDATORY]
        if [k for k in keys if k in want] != want:
            raise ContractError(f"mandatory fields {want} expected in that order, got {keys}")
        if "velocity_wind" in doc and keys.index("velocity_wind") < keys.index("velocity"):
            raise ContractError("velocity_wind before velocity")
        imu = doc["imu"]
        if list(imu) != ["gyro", "accel_body"]:
            raise ContractError(f"imu: expected gyro then accel_body, got {list(imu)}")
        for name, n in (("position", 3), ("velocity", 3), ("quaternion", 4)):
            if name in doc and len(doc[name]) != n:
                raise ContractError(f"{name}: expected {n} numbers, got {doc[name]}")
        if self.last is not None and doc["timestamp"] < self.last["timestamp"]:
            raise ContractError(f"timestamp went back: {doc['timestamp']} after "
                                f"{self.last['timestamp']}")
        self.last = doc
        return dict(doc)

    def frame(self, pwm: list[int]) -> dict[str, Any]:
        """Send the next frame and wait for its answer (lockstep)."""
        self.frame_count += 1
        t0 = time.perf_counter_ns()
        self.send_raw(self.packet(pwm))
        doc = self.receive()
        self.rtt_us.append((time.perf_counter_ns() - t0) / 1e3)
        return doc

    def fly(self, frames: int, pilot: Callable[[dict[str, Any] | None], list[int]] | None = None,
            paced: bool = False) -> list[dict[str, Any]]:
        """``frames`` lockstep frames flown by ``pilot`` (:class:`WingLeveler` by default);
        ``paced``: no faster than ``frame_rate`` (wall clock). Returns the answers."""
        pilot = pilot or WingLeveler()
        out = []
        period = 1.0 / self.frame_rate
        due = time.perf_counter()
        for _ in range(frames):
            if paced:
                due += period
                time.sleep(max(0.0, due - time.perf_counter()))
            out.append(self.frame(pilot(self.last)))
        return out

    def restart(self) -> None:
        """What a restarted SITL does: its frame counter starts again."""
        self.frame_count = 0
        self.last = None
