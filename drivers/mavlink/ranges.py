"""Echoes into an autopilot's estimator: ``DISTANCE_SENSOR`` per ear, ``OBSTACLE_DISTANCE``.

Every range comes from the *echo* by echoloop's one rule (:mod:`sim_core.sensors.echo_range`:
the first return above a threshold, by time of flight), never from the scene's geometry.

``DISTANCE_SENSOR`` (one per ear: ``id`` = the sonar's ``sensor_id`` + the ear's index):

* ``current_distance`` cm: the first return's range; no return: ``max_distance`` + 1 cm (out
  of range high: nothing within reach); ``min_distance``, ``max_distance`` cm from the spec;
* ``orientation``: the beam's axis in the vehicle's body (the echo's ``boresight_body``) as the
  nearest of MAVLink's forward-to-left yaws (0-7: every 45°, clockwise seen from above), up
  (24) or down (25) within ``orientation_tolerance_deg``, else ``MAV_SENSOR_ROTATION_CUSTOM``
  (100) with ``quaternion`` the body-FRD-from-sensor rotation of the axis (PX4 takes it;
  ArduPilot takes only a range finder whose orientation equals its ``RNGFNDx_ORIENT``);
  a sonar's ``orientation`` overrides it;
* ``covariance``: the square of ``sigma_m`` in cm² (the rule's error on a flat ground is up to
  2 cm: ``tests/sim_core/sensors/test_echo_range.py``); ``type`` ULTRASOUND; ``horizontal_fov``
  and ``vertical_fov`` the beam's ``fov_deg`` (0: unknown); ``signal_quality`` 1..100 from
  the return's level above the rule's absolute threshold, its noise floor (60 dB or more:
  100), 0 (unknown) for no return; ``time_boot_ms`` the ping's emission, sim time.

``OBSTACLE_DISTANCE`` (optional per sonar): 72 sectors of 5° around the body (frame
``MAV_FRAME_BODY_FRD``, sector 0 centred ahead, clockwise), the ones the beam covers
(its axis' azimuth ± half the ``fov_deg``, at least the sector of the axis) set to the range
(or ``max_distance`` + 1: clear), the others ``UINT16_MAX`` (not measured by this ping). A
beam more than 45° from the body's horizontal plane measures no horizontal obstacle: none is
sent (``obstacle_skipped``).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.mavlink.link import MavlinkLink, mavlink
from hil_bridge.bus.faults import Faults
from sim_core.pose import frd_from_flu, quat_between
from sim_core.sensors import RangeRule, echo_ranges

__all__ = ["ORIENTATIONS", "EchoRanger", "RangeFinderSpec", "RangeSender", "SonarRange",
           "orientation_of"]

#: MAV_SENSOR_ORIENTATION of a range finder's axis, body FRD unit vectors
ORIENTATIONS: dict[int, tuple[float, float, float]] = {
    **{k: (math.cos(math.radians(45 * k)), math.sin(math.radians(45 * k)), 0.0)
       for k in range(8)},
    24: (0.0, 0.0, -1.0),
    25: (0.0, 0.0, 1.0),
}
CUSTOM = 100
_NO_DATA = 65535
_SECTORS = 72


@dataclass(frozen=True, slots=True)
class SonarRange:
    """One sonar as range finder(s): its ``sensor_id`` (ear e is ``sensor_id + e``), an
    ``orientation`` to send whatever the mount (None: from the beam), its beam's ``fov_deg``
    (0: unknown) and whether it also sends ``OBSTACLE_DISTANCE``."""

    sonar_id: int = 0
    sensor_id: int = 0
    orientation: int | None = None
    fov_deg: float = 0.0
    obstacle_distance: bool = False

    def __post_init__(self) -> None:
        if not 0 <= self.sensor_id <= 250:
            raise ValueError(f"sensor_id: expected 0..250, got {self.sensor_id}")
        if self.orientation is not None and self.orientation not in (*ORIENTATIONS, CUSTOM):
            raise ValueError(f"orientation: expected one of {[*ORIENTATIONS, CUSTOM]}, got "
                             f"{self.orientation}")
        if not 0 <= self.fov_deg < 180:
            raise ValueError(f"fov_deg: expected 0 <= fov < 180, got {self.fov_deg}")


@dataclass(frozen=True, slots=True)
class RangeFinderSpec:
    """The range finders of a link: ``sonars``, the echo → range rule's parameters, the range
    reported (``min_distance_m``, ``max_distance_m``: the echo model hears leaves out to 10 m
    on the beam's axis), ``sigma_m`` and ``orientation_tolerance_deg``."""

    sonars: tuple[SonarRange, ...] = (SonarRange(),)
    threshold_db: float = -100.0
    relative_db: float = -25.0
    sound_speed: float = 340.0
    min_distance_m: float = 0.2
    max_distance_m: float = 10.0
    sigma_m: float = 0.02
    orientation_tolerance_deg: float = 5.0
    rule: RangeRule = field(init=False)

    def __post_init__(self) -> None:
        ids = [s.sonar_id for s in self.sonars]
        if len(set(ids)) != len(ids):
            raise ValueError(f"sonars: a sonar listed twice: {ids}")
        if not 0 <= self.min_distance_m < self.max_distance_m <= 600:
            raise ValueError(f"min_distance_m, max_distance_m: expected 0 <= min < max <= 600, "
                             f"got {self.min_distance_m}, {self.max_distance_m}")
        if not 0 <= self.sigma_m <= 1.0:
            raise ValueError(f"sigma_m: expected 0 <= sigma <= 1 m, got {self.sigma_m}")
        if not 0 <= self.orientation_tolerance_deg <= 45:
            raise ValueError(f"orientation_tolerance_deg: expected 0..45, got "
                             f"{self.orientation_tolerance_deg}")
        object.__setattr__(self, "rule", RangeRule(
            threshold_db=self.threshold_db, relative_db=self.relative_db,
            sound_speed=self.sound_speed, min_range_m=self.min_distance_m))


def orientation_of(axis_frd: np.ndarray, tolerance_deg: float) -> tuple[int, list[float]]:
    """The MAV_SENSOR_ORIENTATION of a unit axis (3,) body FRD and the quaternion to send:
    the nearest standard one within ``tolerance_deg`` (quaternion zeros), else CUSTOM with
    the body-from-sensor rotation taking the forward axis onto ``axis_frd``."""
    best, best_cos = CUSTOM, math.cos(math.radians(tolerance_deg))
    for code, d in ORIENTATIONS.items():
        c = float(np.dot(axis_frd, d))
        if c >= best_cos:
            best, best_cos = code, c
    if best != CUSTOM:
        return best, [0.0, 0.0, 0.0, 0.0]
    q = quat_between(np.array([1.0, 0.0, 0.0]), axis_frd)
    return CUSTOM, [float(v) for v in q]


class EchoRanger:
    """Turns echoes into range-finder messages by a :class:`RangeFinderSpec`; counts what it
    did (:attr:`counters`)."""

    def __init__(self, spec: RangeFinderSpec) -> None:
        self.spec = spec
        self.by_id = {s.sonar_id: s for s in spec.sonars}
        self.counters = dict.fromkeys(("echoes", "returns", "no_returns", "distance_messages",
                                       "obstacle_messages", "obstacle_skipped",
                                       "echoes_unoriented", "echoes_bad"), 0)
        #: the last range of every (sonar, ear): m, NaN for no return
        self.last: dict[tuple[int, int], float] = {}

    def messages(self, echo: Any) -> list[Any]:
        """The MAVLink messages for one ``SonarEcho`` of a listed sonar."""
        sonar = self.by_id[int(echo.sonar_id)]
        spec, c = self.spec, self.counters
        c["echoes"] += 1
        try:
            ranges = echo_ranges(echo.samples, float(echo.fs), spec.rule)
        except ValueError:
            c["echoes_bad"] += 1
            return []
        axis_flu = np.asarray(echo.boresight_body, dtype=np.float64)
        if sonar.orientation is None and not np.all(np.isfinite(axis_flu)):
            c["echoes_unoriented"] += 1
            return []
        axis = frd_from_flu(axis_flu) if np.all(np.isfinite(axis_flu)) else np.array(
            ORIENTATIONS.get(sonar.orientation or 0, (1.0, 0.0, 0.0)))
        axis = axis / np.linalg.norm(axis)
        if sonar.orientation is None:
            orient, quat = orientation_of(axis, spec.orientation_tolerance_deg)
        else:
            orient = sonar.orientation
            quat = orientation_of(axis, 0.0)[1] if orient == CUSTOM else [0.0] * 4
        lo, hi = round(spec.min_distance_m * 100), round(spec.max_distance_m * 100)
        cov = min(254, round((spec.sigma_m * 100) ** 2))
        fov = math.radians(sonar.fov_deg)
        t_ms = (int(echo.emit_ns or echo.stamp_ns) // 1_000_000) & 0xFFFFFFFF
        out: list[Any] = []
        cm: list[int] = []
        for ear, (r, level) in enumerate(zip(ranges.range_m.tolist(), ranges.level_db.tolist(),
                                             strict=True)):
            self.last[(sonar.sonar_id, ear)] = r
            if math.isnan(r) or r > spec.max_distance_m:
                c["no_returns"] += 1
                dist, quality = hi + 1, 0
            else:
                c["returns"] += 1
                dist = round(r * 100)
                quality = max(1, min(100, round(100 * (level - spec.threshold_db) / 60.0)))
            cm.append(dist)
            out.append(mavlink.MAVLink_distance_sensor_message(
                t_ms, lo, hi, min(dist, _NO_DATA - 1), mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND,
                sonar.sensor_id + ear, orient, cov, fov, fov, quat, quality))
        c["distance_messages"] += len(out)
        if sonar.obstacle_distance and cm:
            msg = self._obstacle(echo, axis, min(cm), lo, hi, fov)
            if msg is None:
                c["obstacle_skipped"] += 1
            else:
                out.append(msg)
                c["obstacle_messages"] += 1
        return out

    @staticmethod
    def _obstacle(echo: Any, axis: np.ndarray, dist_cm: int, lo: int, hi: int,
                  fov: float) -> Any | None:
        """``OBSTACLE_DISTANCE`` of the sectors the beam covers (module docstring)."""
        horizontal = math.hypot(float(axis[0]), float(axis[1]))
        if horizontal < math.cos(math.radians(45.0)):
            return None
        azimuth = math.degrees(math.atan2(float(axis[1]), float(axis[0])))  # FRD: + right
        half = max(math.degrees(fov) / 2.0, 0.0)
        distances = [_NO_DATA] * _SECTORS
        first = math.floor((azimuth - half) / 5.0 + 0.5)
        last = math.floor((azimuth + half) / 5.0 + 0.5)
        for k in range(first, last + 1):
            distances[k % _SECTORS] = min(dist_cm, hi + 1)
        return mavlink.MAVLink_obstacle_distance_message(
            int(echo.emit_ns or echo.stamp_ns) // 1000, mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND,
            distances, 5, lo, hi, 5.0, 0.0, mavlink.MAV_FRAME_BODY_FRD)


class RangeSender:
    """Echoes in (:meth:`submit`, from a bus callback), range-finder messages out on a link,
    from a thread of its own (the rule takes a Hilbert transform of each echo: it never holds
    a bus callback up). The newest 64 echoes wait; older ones are dropped
    (``echoes_dropped``)."""

    def __init__(self, spec: RangeFinderSpec, name: str) -> None:
        self.ranger = EchoRanger(spec)
        self._name = name
        self._cond = threading.Condition()
        self._queue: deque[Any] = deque()
        self._stop = False
        self._thread: threading.Thread | None = None
        self._c = {"ranges_sent": 0, "echoes_dropped": 0}

    def start(self, link: MavlinkLink, faults: Faults) -> None:
        self._thread = threading.Thread(
            target=faults.guarded("ranges", lambda: self._loop(link)),
            name=f"{self._name}-ranges", daemon=True)
        self._thread.start()

    def submit(self, echo: Any) -> None:
        with self._cond:
            if len(self._queue) >= 64:
                self._queue.popleft()
                self._c["echoes_dropped"] += 1
            self._queue.append(echo)
            self._cond.notify()

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def counters(self) -> dict[str, int]:
        with self._cond:
            return {**self._c, **self.ranger.counters}

    def _loop(self, link: MavlinkLink) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                echo = self._queue.popleft()
            messages = self.ranger.messages(echo)
            if messages and link.send_many(messages):
                with self._cond:
                    self._c["ranges_sent"] += len(messages)
