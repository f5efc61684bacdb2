"""A protocol double of PX4's simulator interface, written from its contract, for tests and
benchmarks where no PX4 runs (``docs/px4.md``).

:class:`Px4Double` is PX4's side of the wire (``src/modules/simulation/simulator_mavlink``):
it connects to the simulator (TCP, as PX4 SITL does, or a serial port, as HITL's USB), sends
a ``HEARTBEAT`` and reads what the simulator sends, checking what PX4 relies on and raising
:class:`ContractError` otherwise:

- ``HIL_SENSOR``: ``id`` 0, ``fields_updated`` with every group PX4 takes (accel, gyro, mag,
  baro, differential pressure: 0x1FFF), every value finite, ``time_usec`` rising on one
  connection;
- in lockstep, once its controls flow, ``time_usec`` steps by exactly the period, and no
  ``HIL_SENSOR`` comes before the controls answering the last one (every ``probe_every``-th
  answer is held back ``probe_s`` to see that none does);
- ``HIL_GPS``: a 3-D fix of finite values; ``HIL_STATE_QUATERNION``: a unit quaternion;
  ``DISTANCE_SENSOR``: ``min_distance`` < ``max_distance``.

Every ``HIL_SENSOR`` sent with a ``HIL_STATE_QUATERNION`` of the same ``time_usec`` is kept
with it (``pairs`` of the report), so a test can hold the sensors to closed forms of the
truth.

Like a booting PX4 it answers nothing for its first ``boot_steps`` sensors (the simulator runs
on in real time until its first controls), then answers each ``HIL_SENSOR`` in lockstep
(``flags`` bit 0) or, in HITL (``lockstep=False``), sends controls at ``controls_hz`` of the
wall clock whatever arrives. Its pilot, :class:`Pilot`, is just enough to fly a glider on the
sensors it is sent: bank held by roll control from the ground truth's attitude and the gyro,
airspeed by pitch control from the differential pressure.

``python -m drivers.mocks.px4_double --url tcp://127.0.0.1:4560 --steps 1000`` runs it as a
process of its own and prints what it saw as JSON (the tests and ``bench`` use it so).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import socket
import sys
import time
import urllib.parse
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

__all__ = ["ContractError", "Pilot", "Px4Double", "main"]

_ALL_FIELDS = 0x1FFF
_RHO0 = 1.225


class ContractError(AssertionError):
    """What the simulator sent breaks PX4's contract."""


@dataclass
class Pilot:
    """PX4-sense controls (roll + right, pitch + up, yaw + right, throttle): roll holds
    ``bank_deg`` from the truth's attitude and the gyro's roll rate; pitch holds
    ``airspeed_mps`` (from the differential pressure, sea-level density) about ``trim``."""

    bank_deg: float = 0.0
    airspeed_mps: float = 19.5
    trim: float = 0.15
    k_roll: float = 1.5
    k_rate: float = 0.3
    k_speed: float = 0.03

    def __call__(self, roll: float, roll_rate: float, diff_pressure_hpa: float) -> list[float]:
        speed = math.sqrt(max(0.0, 2.0 * diff_pressure_hpa * 100.0 / _RHO0))
        ail = self.k_roll * (math.radians(self.bank_deg) - roll) - self.k_rate * roll_rate
        ele = self.trim + self.k_speed * (speed - self.airspeed_mps)
        out = [0.0] * 16
        out[0] = min(max(ail, -1.0), 1.0)
        out[1] = min(max(ele, -1.0), 1.0)
        return out


@dataclass
class Px4Double:
    """PX4's end of the simulator link (module docstring) at ``url``: ``tcp://HOST:PORT`` or
    ``serial:///dev/pts/N`` (the end a pty's other side is opened by the simulator), or
    ``pty://LINK`` (it makes the pty, linked at LINK, and the simulator opens it)."""

    url: str
    rate_hz: float = 250.0
    lockstep: bool = True
    boot_steps: int = 25
    controls_hz: float = 200.0
    timeout_s: float = 10.0
    probe_every: int = 50
    probe_s: float = 0.02
    pilot: Pilot = field(default_factory=Pilot)
    counts: dict[str, int] = field(default_factory=dict)
    rtt_us: list[float] = field(default_factory=list)
    sensor_times: list[int] = field(default_factory=list)
    gps_times: list[int] = field(default_factory=list)
    wall_times: list[float] = field(default_factory=list)
    last: dict[str, Any] = field(default_factory=dict)
    distances: list[dict[str, Any]] = field(default_factory=list)
    pairs: list[dict[str, Any]] = field(default_factory=list)
    bytes_in: int = 0

    def __post_init__(self) -> None:
        self._tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self._rx = mavlink.MAVLink(None)
        self._rx.robust_parsing = True
        self._sock: socket.socket | None = None
        self._fd = -1
        self._pty: Any = None
        self._queue: list[Any] = []
        self._roll = 0.0
        self._first = 0
        self._sent_at = 0.0
        self.path = ""

    # ------------------------------------------------------------------ the wire

    def connect(self) -> None:
        """Open the link and say hello (PX4 sends one HEARTBEAT to start the simulator)."""
        parts = urllib.parse.urlsplit(self.url)
        if parts.scheme == "tcp":
            deadline = time.monotonic() + self.timeout_s
            while True:
                try:
                    self._sock = socket.create_connection((parts.hostname, parts.port), 1.0)
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.05)
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        elif parts.scheme == "serial":
            import serial  # the simulator's end is a tty like a Pixhawk's USB

            self._serial = serial.Serial(parts.path, 921600, timeout=0)
            self._fd = self._serial.fileno()
        elif parts.scheme == "pty":
            from drivers.serial.ptyport import PtyPort

            self._pty = PtyPort(parts.path or None)
            self.path = str(self._pty.link or self._pty.path)
            self._fd = -2
        else:
            raise ValueError(f"url: expected tcp://, serial:// or pty://, got {self.url!r}")
        self._queue.clear()
        self._first = len(self.sensor_times)  # a new connection: a new PX4 process
        self._rx = mavlink.MAVLink(None)
        self._rx.robust_parsing = True
        self.send(mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_PX4, 0, 0,
            mavlink.MAV_STATE_STANDBY, 3))

    def close(self) -> None:
        """Drop the link, as a PX4 that exits does."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        if self._fd >= 0:
            self._serial.close()
            self._fd = -1
        if self._pty is not None:
            self._pty.close()
            self._pty = None

    def send(self, msg: Any) -> None:
        self.send_raw(msg.pack(self._tx))

    def send_raw(self, data: bytes) -> None:
        """Write bytes as they are (a corrupt frame, garbage)."""
        if self._sock is not None:
            self._sock.sendall(data)
        elif self._pty is not None:
            self._pty.write(data)
        else:
            os.write(self._fd, data)

    def _read(self, timeout_s: float) -> bytes:
        if self._pty is not None:
            return bytes(self._pty.read(65536, timeout_s))
        fd = self._sock.fileno() if self._sock is not None else self._fd
        ready, _, _ = select.select([fd], [], [], timeout_s)
        if not ready:
            return b""
        if self._sock is not None:
            data = self._sock.recv(65536)
            if not data:
                raise ContractError("the simulator closed the connection")
            return data
        return os.read(fd, 65536)

    def receive(self, timeout_s: float | None = None) -> Any:
        """The next message from the simulator, checked (:class:`ContractError`)."""
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while not self._queue:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"nothing from the simulator in {self.timeout_s} s")
            data = self._read(left)
            self.bytes_in += len(data)
            for m in self._rx.parse_buffer(data) or ():
                if m.get_type() == "BAD_DATA":
                    raise ContractError(f"a corrupt frame from the simulator: {m}")
                self._queue.append(m)
        msg = self._queue.pop(0)
        self._check(msg)
        return msg

    # ------------------------------------------------------------------ the contract

    def _check(self, m: Any) -> None:
        kind = m.get_type()
        self.counts[kind] = self.counts.get(kind, 0) + 1
        values: list[float] = []
        if kind == "HIL_SENSOR":
            if m.id != 0 or m.fields_updated != _ALL_FIELDS:
                raise ContractError(f"HIL_SENSOR id {m.id}, fields_updated "
                                    f"{m.fields_updated:#x}: expected 0 and {_ALL_FIELDS:#x}")
            if self.sensor_times[self._first:] and m.time_usec <= self.sensor_times[-1]:
                raise ContractError(f"HIL_SENSOR time_usec went back or stood: {m.time_usec} "
                                    f"after {self.sensor_times[-1]}")
            values = [m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro, m.xmag, m.ymag, m.zmag,
                      m.abs_pressure, m.diff_pressure, m.pressure_alt, m.temperature]
            self.sensor_times.append(int(m.time_usec))
            self.wall_times.append(time.monotonic())
        elif kind == "HIL_GPS":
            if m.fix_type != 3:
                raise ContractError(f"HIL_GPS fix_type {m.fix_type}: expected a 3-D fix")
            self.gps_times.append(int(m.time_usec))
            values = [m.lat, m.lon, m.alt, m.vn, m.ve, m.vd]
        elif kind == "HIL_STATE_QUATERNION":
            q = np.array(m.attitude_quaternion, dtype=float)
            if abs(float(np.linalg.norm(q)) - 1.0) > 1e-5:
                raise ContractError(f"HIL_STATE_QUATERNION not a unit quaternion: {q}")
            w, x, y, z = q
            self._roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
            sensor = self.last.get("HIL_SENSOR")
            if sensor is not None and sensor.time_usec == m.time_usec:
                self.pairs.append({"sensor": sensor.to_dict(), "truth": m.to_dict()})
            values = [*q, m.rollspeed, m.pitchspeed, m.yawspeed]
        elif kind == "DISTANCE_SENSOR":
            if not m.min_distance < m.max_distance:
                raise ContractError(f"DISTANCE_SENSOR min {m.min_distance} >= max "
                                    f"{m.max_distance}")
            self.distances.append({k: getattr(m, k) for k in (
                "time_boot_ms", "current_distance", "min_distance", "max_distance", "id",
                "orientation", "covariance", "signal_quality")} | {
                "quaternion": list(m.quaternion)})
        if not all(math.isfinite(v) for v in values):
            raise ContractError(f"{kind} with a non-finite value: {m}")
        self.last[kind] = m

    # ------------------------------------------------------------------ flying

    def controls(self) -> Any:
        """The pilot's ``HIL_ACTUATOR_CONTROLS`` from the last sensors and truth."""
        s = self.last.get("HIL_SENSOR")
        u = self.pilot(self._roll, 0.0 if s is None else float(s.xgyro),
                       0.0 if s is None else float(s.diff_pressure))
        t = 0 if s is None else int(s.time_usec)
        flags = 1 if self.lockstep else 0
        return mavlink.MAVLink_hil_actuator_controls_message(
            t, u, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
            flags)

    def step(self) -> Any:
        """Wait for the next ``HIL_SENSOR`` (taking everything before it), answer it once
        booted; returns it."""
        while True:
            m = self.receive()
            if m.get_type() != "HIL_SENSOR":
                continue
            now = time.perf_counter()
            if self._sent_at:
                self.rtt_us.append((now - self._sent_at) * 1e6)
                self._sent_at = 0.0
            if len(self.sensor_times) > self.boot_steps:
                answered = self.counts.get("controls", 0)
                if self.probe_every and answered % self.probe_every == self.probe_every - 1:
                    self._probe()
                self.counts["controls"] = answered + 1
                self._sent_at = time.perf_counter()
                self.send(self.controls())
            return m

    def _probe(self) -> None:
        """Hold an answer back for ``probe_s``: in lockstep no HIL_SENSOR may come meanwhile."""
        deadline = time.monotonic() + self.probe_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                m = self.receive(left)
            except TimeoutError:
                return
            if m.get_type() == "HIL_SENSOR":
                raise ContractError(f"a HIL_SENSOR (time_usec {m.time_usec}) before the "
                                    "controls answering the last one")

    def fly(self, steps: int) -> None:
        """``steps`` sensors received (lockstep: answered once booted), then a check of the
        lockstep period over the answered ones."""
        if not self.lockstep:
            self._fly_free(steps)
            return
        for _ in range(steps):
            self.step()
        answered = self.sensor_times[self.boot_steps + 1:]
        if len(answered) > 1:
            step_us = np.diff(answered)
            want = round(1e6 / self.rate_hz)
            if not np.all(step_us == want):
                raise ContractError(f"lockstep time_usec steps {sorted(set(step_us.tolist()))}"
                                    f": expected exactly {want} µs")

    def _fly_free(self, steps: int) -> None:
        """HITL: controls at ``controls_hz`` of the wall clock, sensors read as they come."""
        period = 1.0 / self.controls_hz
        due = time.monotonic()
        seen = len(self.sensor_times)
        while len(self.sensor_times) - seen < steps:
            if time.monotonic() >= due:
                due += period
                if len(self.sensor_times) > self.boot_steps:
                    self.counts["controls"] = self.counts.get("controls", 0) + 1
                    self.send(self.controls())
            try:
                self.receive(max(0.0, due - time.monotonic()))
            except TimeoutError:
                continue

    def report(self) -> dict[str, Any]:
        """What it saw, as plain data."""
        s = self.last.get("HIL_SENSOR")
        truth = self.last.get("HIL_STATE_QUATERNION")
        gps = self.last.get("HIL_GPS")
        return {
            "counts": self.counts, "sensor_times": self.sensor_times, "gps_times": self.gps_times,
            "wall_times": self.wall_times, "rtt_us": self.rtt_us, "bytes_in": self.bytes_in,
            "distances": self.distances, "roll": self._roll, "pairs": self.pairs,
            "last_sensor": None if s is None else s.to_dict(),
            "last_truth": None if truth is None else truth.to_dict(),
            "last_gps": None if gps is None else gps.to_dict(),
        }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m drivers.mocks.px4_double",
                                description="PX4's side of the simulator link, checked.")
    p.add_argument("--url", required=True, help="tcp://HOST:PORT, serial:///DEV or pty://LINK")
    p.add_argument("--steps", type=int, default=1000, help="sensors to take")
    p.add_argument("--rate-hz", type=float, default=250.0)
    p.add_argument("--boot-steps", type=int, default=25, help="sensors left unanswered first")
    p.add_argument("--hitl", action="store_true", help="no lockstep: controls on the wall clock")
    p.add_argument("--bank-deg", type=float, default=0.0)
    p.add_argument("--reconnect-after", type=int, default=0,
                   help="close and connect again after this many steps (a restarted PX4)")
    p.add_argument("--garbage", action="store_true",
                   help="also send garbage, a corrupt frame, an unknown message and NaN controls")
    p.add_argument("--timeout", type=float, default=30.0)
    args = p.parse_args(argv)
    double = Px4Double(args.url, rate_hz=args.rate_hz, lockstep=not args.hitl,
                       boot_steps=args.boot_steps, timeout_s=args.timeout,
                       pilot=Pilot(bank_deg=args.bank_deg))
    double.connect()
    if double.path:
        print(json.dumps({"pty": double.path}), flush=True)
    try:
        if args.garbage:
            _send_garbage(double)
        if args.reconnect_after:
            double.fly(args.reconnect_after)
            double.close()
            double.boot_steps = len(double.sensor_times) + args.boot_steps
            double.connect()
        double.fly(args.steps - args.reconnect_after)
    except (ContractError, TimeoutError) as exc:
        print(json.dumps({"error": f"{type(exc).__name__}: {exc}", **double.report()}))
        return 1
    finally:
        double.close()
    print(json.dumps(double.report()))
    return 0


def _send_garbage(double: Px4Double) -> None:
    """What a noisy link or a confused peer sends: counted by the simulator, never flown."""
    double.send_raw(b"\x00\xffnot mavlink at all\xfd\x01")
    good = bytearray(double.controls().pack(double._tx))
    good[-1] ^= 0xFF
    double.send_raw(bytes(good))  # a checksum that fails
    unknown = bytearray(mavlink.MAVLink_heartbeat_message(0, 8, 0, 0, 0, 3).pack(double._tx))
    unknown[7:10] = b"\xee\xee\x00"  # a message id the dialect has not
    double.send_raw(bytes(unknown))
    nan = [math.nan] + [0.0] * 15
    double.send(mavlink.MAVLink_hil_actuator_controls_message(0, nan, 0, 1))


if __name__ == "__main__":
    sys.exit(main())
