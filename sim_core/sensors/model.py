"""What an autopilot's sensors read on a vehicle: IMU, barometer, pitot, magnetometer, GNSS.

:class:`SensorSuite` turns the truth of N vehicles (:class:`SensorTruth`, e.g. a 6-DoF
glider's state in the scene's air mass) into readings, sample after sample, with seeded noise
(or none: ``SensorSpec(noise=False)`` reads the truth exactly, for tests). Frames are
echoloop's (world ENU, body FLU); an edge that speaks NED/FRD converts there.

===============  ===========================================  ============  ==================
reading          model                                        unit, frame   noise (defaults)
===============  ===========================================  ============  ==================
``accel``        specific force (what an accelerometer        m/s², body    white 4.0e-3
                 reads: +g up at rest) + bias                 FLU           /√Hz; bias random
                                                                            walk 6.0e-3 /s/√Hz
``gyro``         body rates + bias                            rad/s, FLU    white 3.394e-4
                                                                            /√Hz; bias walk
                                                                            3.8785e-5 /s/√Hz
``mag``          the WMM2025 field at the vehicle, in body    gauss, FLU    white 4.0e-4 /√Hz
                 axes (:mod:`sim_core.sensors.magnetic`)
``abs_pressure`` ISA static pressure at the height            Pa            white σ 1.0 Pa
``diff_pressure`` ½ ρ V² at the true airspeed through the     Pa            white σ 1.0 Pa
                 moving air, ρ from the ISA
``pressure_alt`` ISA height of the measured static pressure   m
``temperature``  ISA temperature at the height                °C            none
GNSS             :mod:`sim_core.sensors.gps`                  deg, m, ENU   see there
===============  ===========================================  ============  ==================

White noise is given as a density: the standard deviation of one sample is the density times
√(1 / dt), dt the time since the previous sample (``rate_hz`` for the first). Biases start at 0
(a calibrated IMU) and wander as random walks. Latency: none for the IMU, barometer, pitot and
magnetometer (a sample describes the instant it is taken); the GNSS fix is late by its
``latency_s``. The field is evaluated where the vehicle is whenever it has moved
``field_update_m`` from where it was last evaluated, looked at every 0.1 s of sim time (the
field changes by a few nT per km).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from sim_core.pose import quat_conjugate, quat_rotate
from sim_core.rng import SeedLike, derive_rng
from sim_core.sensors.atmosphere import dynamic_pressure, isa, pressure_altitude
from sim_core.sensors.gps import GpsFix, GpsReceiver, GpsSpec
from sim_core.sensors.magnetic import WMM_VALID, field_enu

__all__ = ["ImuSpec", "MagSpec", "SensorReadings", "SensorSpec", "SensorSuite", "SensorTruth"]

F8 = NDArray[np.float64]
_T0_C = 273.15
#: how often (sim time) the field's place is looked at
_FIELD_CHECK_NS = 100_000_000


def _non_negative(obj: object, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name}: expected a finite value >= 0, got {v}")


@dataclass(frozen=True, slots=True)
class ImuSpec:
    """Accelerometer and gyroscope noise (module docstring): white noise densities
    (m/s²/√Hz, rad/s/√Hz) and bias random walks (m/s³/√Hz, rad/s²/√Hz): the figures of the
    ADIS16448 IMU model that PX4's Gazebo-classic simulation uses."""

    accel_noise_density: float = 4.0e-3
    accel_random_walk: float = 6.0e-3
    gyro_noise_density: float = 3.394e-4
    gyro_random_walk: float = 3.8785e-5

    def __post_init__(self) -> None:
        _non_negative(self, "accel_noise_density", "accel_random_walk", "gyro_noise_density",
                      "gyro_random_walk")


@dataclass(frozen=True, slots=True)
class MagSpec:
    """The magnetometer: white noise density gauss/√Hz, the decimal year of the WMM2025
    field, and how far (m) the vehicle moves before the field is evaluated again."""

    noise_density: float = 4.0e-4
    epoch_year: float = 2026.0
    field_update_m: float = 100.0

    def __post_init__(self) -> None:
        _non_negative(self, "noise_density")
        lo, hi = WMM_VALID
        if not lo <= self.epoch_year < hi:
            raise ValueError(f"epoch_year: WMM2025 is valid for {lo} <= year < {hi}, got "
                             f"{self.epoch_year}")
        if not self.field_update_m > 0:
            raise ValueError(f"field_update_m: expected > 0, got {self.field_update_m}")


@dataclass(frozen=True, slots=True)
class SensorSpec:
    """Every sensor of a vehicle (module docstring). ``noise``: False reads the truth (no
    draws at all); ``rate_hz``: the nominal sample rate, for the first sample's white noise;
    ``baro_noise_pa``, ``pitot_noise_pa``: white standard deviations per sample."""

    noise: bool = True
    rate_hz: float = 250.0
    imu: ImuSpec = field(default_factory=ImuSpec)
    mag: MagSpec = field(default_factory=MagSpec)
    baro_noise_pa: float = 1.0
    pitot_noise_pa: float = 1.0
    gps: GpsSpec = field(default_factory=GpsSpec)

    def __post_init__(self) -> None:
        if not 0 < self.rate_hz <= 10000:
            raise ValueError(f"rate_hz: expected 0 < rate <= 10000, got {self.rate_hz}")
        _non_negative(self, "baro_noise_pa", "pitot_noise_pa")


@dataclass(frozen=True, slots=True)
class SensorTruth:
    """The truth of N vehicles at one instant: geodetic ``lat_deg``, ``lon_deg`` (N,) and
    ``height_m`` (N,) m (WGS-84, taken as above mean sea level), ``velocity`` (N, 3) m/s
    world ENU, ``quat`` (N, 4) world-from-body ENU-from-FLU, ``rates`` (N, 3) rad/s body
    FLU, ``specific_force`` (N, 3) m/s² body FLU, ``airspeed`` (N,) true airspeed m/s."""

    lat_deg: F8
    lon_deg: F8
    height_m: F8
    velocity: F8
    quat: F8
    rates: F8
    specific_force: F8
    airspeed: F8


@dataclass(frozen=True, slots=True)
class SensorReadings:
    """One sample of N vehicles' sensors (module docstring for units and frames)."""

    t_ns: int
    accel: F8
    gyro: F8
    mag: F8
    abs_pressure: F8
    diff_pressure: F8
    pressure_alt: F8
    temperature: F8


class SensorSuite:
    """The sensors of N vehicles of one :class:`SensorSpec`; ``seed`` (and ``key``, e.g. the
    vehicle ids) addresses their noise stream (:func:`sim_core.rng.derive_rng`): the same seed
    and samples give the same bits."""

    def __init__(self, spec: SensorSpec, n: int, *, seed: SeedLike = 0,
                 key: tuple[int | str, ...] = ()) -> None:
        self.spec = spec
        self.n = int(n)
        self._rng = derive_rng(seed, "sensors", *key) if spec.noise else None
        gps_rng = derive_rng(seed, "sensors-gps", *key) if spec.noise else None
        self.gps = GpsReceiver(spec.gps, self.n, gps_rng)
        self._bias = np.zeros((self.n, 6))  # accel, gyro (FLU)
        imu = spec.imu
        self._white = np.array([imu.accel_noise_density] * 3 + [imu.gyro_noise_density] * 3
                               + [spec.mag.noise_density] * 3)
        self._walk = np.array([imu.accel_random_walk] * 3 + [imu.gyro_random_walk] * 3)
        self._last_ns: int | None = None
        self._field = np.zeros((self.n, 3))
        self._field_at: F8 | None = None  # geodetic where each field was evaluated
        self._field_check_ns = -1

    def sample(self, t_ns: int, truth: SensorTruth) -> SensorReadings:
        """The readings at ``t_ns`` (sim time, rising) of ``truth``; the GNSS receivers
        record it too (:attr:`gps`: ``gps.due(t_ns)``, ``gps.fix(t_ns)``)."""
        spec = self.spec
        geo = np.stack([truth.lat_deg, truth.lon_deg, truth.height_m], axis=-1).reshape(
            self.n, 3)
        self.gps.record(t_ns, geo, truth.velocity)
        b_body = quat_rotate(quat_conjugate(truth.quat), self._field_enu(geo))
        p, t_k, rho = isa(geo[:, 2])
        q = dynamic_pressure(rho, truth.airspeed)
        accel = np.array(truth.specific_force, dtype=np.float64).reshape(self.n, 3)
        gyro = np.array(truth.rates, dtype=np.float64).reshape(self.n, 3)
        if self._rng is not None:
            dt = 1.0 / spec.rate_hz if self._last_ns is None else max(
                (t_ns - self._last_ns) / 1e9, 1e-6)
            z = self._rng.standard_normal((self.n, 17))
            self._bias += z[:, 11:17] * (self._walk * math.sqrt(dt))
            white = z[:, :9] * (self._white / math.sqrt(dt))
            accel = accel + self._bias[:, :3] + white[:, :3]
            gyro = gyro + self._bias[:, 3:] + white[:, 3:6]
            b_body = b_body + white[:, 6:9]
            p = p + spec.baro_noise_pa * z[:, 9]
            q = q + spec.pitot_noise_pa * z[:, 10]
        self._last_ns = int(t_ns)
        return SensorReadings(t_ns=int(t_ns), accel=accel, gyro=gyro, mag=b_body,
                              abs_pressure=p, diff_pressure=q, pressure_alt=pressure_altitude(p),
                              temperature=t_k - _T0_C)

    def gps_fix(self, t_ns: int) -> GpsFix | None:
        """The GNSS fix reported at ``t_ns`` when one is due, else None."""
        return self.gps.fix(t_ns) if self.gps.due(t_ns) else None

    def _field_enu(self, geo: F8) -> F8:
        """The field (N, 3) gauss ENU at each vehicle, evaluated again where a vehicle moved
        ``field_update_m`` from where it was last evaluated."""
        at = self._field_at
        if at is not None and self._last_ns is not None and self._last_ns < self._field_check_ns:
            return self._field
        self._field_check_ns = (self._last_ns or 0) + _FIELD_CHECK_NS
        if at is None:
            stale = np.ones(self.n, dtype=bool)
        else:
            dn = np.radians(geo[:, 0] - at[:, 0]) * 6.371e6
            de = np.radians(geo[:, 1] - at[:, 1]) * 6.371e6 * np.cos(np.radians(geo[:, 0]))
            moved = dn * dn + de * de + (geo[:, 2] - at[:, 2]) ** 2
            stale = moved > self.spec.mag.field_update_m ** 2
        if stale.any():
            self._field[stale] = field_enu(geo[stale, 0], geo[stale, 1], geo[stale, 2],
                                           self.spec.mag.epoch_year)
            at = geo.copy() if at is None else np.where(stale[:, None], geo, at)
            self._field_at = at
        return self._field
