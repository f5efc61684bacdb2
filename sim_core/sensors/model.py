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

One sample of every vehicle is one compiled pass (:func:`sim_core.sensors.kernels.sample_into`,
the one implementation). White noise is given as a density: the standard deviation of one
sample is the density times √(1 / dt), dt the time since the previous sample (``rate_hz`` for
the first). Biases start at 0
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
from numpy.typing import ArrayLike, NDArray

from sim_core.rng import SeedLike, derive_rng
from sim_core.sensors.gps import GpsFix, GpsReceiver, GpsSpec
from sim_core.sensors.kernels import TRUTH_COLUMNS, sample_into
from sim_core.sensors.magnetic import WMM_VALID, field_enu

__all__ = ["ImuSpec", "MagSpec", "SensorReadings", "SensorSpec", "SensorSuite", "SensorTruth"]

F8 = NDArray[np.float64]
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
    """The truth of N vehicles at one instant, one row each of ``table`` (N, 17)
    (:data:`~sim_core.sensors.kernels.TRUTH_COLUMNS`); its views: ``geodetic`` (N, 3)
    latitude, longitude deg and height m (WGS-84, taken as above mean sea level),
    ``velocity`` (N, 3) m/s world ENU, ``quat`` (N, 4) world-from-body ENU-from-FLU,
    ``rates`` (N, 3) rad/s body FLU, ``specific_force`` (N, 3) m/s² body FLU, ``airspeed``
    (N,) true airspeed m/s. :meth:`of` builds one from those arrays."""

    table: F8

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.table, dtype=np.float64)
        if t.ndim != 2 or t.shape[1] != len(TRUTH_COLUMNS):
            raise ValueError(f"table: expected shape (N, {len(TRUTH_COLUMNS)}), got {t.shape}")
        object.__setattr__(self, "table", t)

    @classmethod
    def of(cls, geodetic: ArrayLike, velocity: ArrayLike, quat: ArrayLike, rates: ArrayLike,
           specific_force: ArrayLike, airspeed: ArrayLike) -> SensorTruth:
        parts = [np.asarray(a, dtype=np.float64) for a in (geodetic, velocity, quat, rates,
                                                           specific_force)]
        n = parts[0].reshape(-1, 3).shape[0]
        return cls(np.concatenate([*(a.reshape(n, -1) for a in parts),
                                   np.asarray(airspeed, dtype=np.float64).reshape(n, 1)], 1))

    @property
    def geodetic(self) -> F8:
        return self.table[:, 0:3]

    @property
    def velocity(self) -> F8:
        return self.table[:, 3:6]

    @property
    def quat(self) -> F8:
        return self.table[:, 6:10]

    @property
    def rates(self) -> F8:
        return self.table[:, 10:13]

    @property
    def specific_force(self) -> F8:
        return self.table[:, 13:16]

    @property
    def airspeed(self) -> F8:
        return self.table[:, 16]


@dataclass(frozen=True, slots=True)
class SensorReadings:
    """One sample of N vehicles' sensors at sim time ``t_ns``, one row each of ``table``
    (N, 14) (:data:`~sim_core.sensors.kernels.READING_COLUMNS`); its views (module docstring
    for units and frames): ``accel``, ``gyro``, ``mag`` (N, 3), ``abs_pressure``,
    ``diff_pressure``, ``pressure_alt``, ``temperature`` (N,), and the ISA ``density``
    kg/m³ where each vehicle is (the truth, for edges that report an indicated airspeed)."""

    t_ns: int
    table: F8

    @property
    def accel(self) -> F8:
        return self.table[:, 0:3]

    @property
    def gyro(self) -> F8:
        return self.table[:, 3:6]

    @property
    def mag(self) -> F8:
        return self.table[:, 6:9]

    @property
    def abs_pressure(self) -> F8:
        return self.table[:, 9]

    @property
    def diff_pressure(self) -> F8:
        return self.table[:, 10]

    @property
    def pressure_alt(self) -> F8:
        return self.table[:, 11]

    @property
    def temperature(self) -> F8:
        return self.table[:, 12]

    @property
    def density(self) -> F8:
        return self.table[:, 13]


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
        self._no_noise = np.zeros((0, 17))
        self._walk = np.array([imu.accel_random_walk] * 3 + [imu.gyro_random_walk] * 3)
        self._last_ns: int | None = None
        self._field = np.zeros((self.n, 3))
        self._field_at: F8 | None = None  # geodetic where each field was evaluated
        self._field_check_ns = -1

    def sample(self, t_ns: int, truth: SensorTruth) -> SensorReadings:
        """The readings at ``t_ns`` (sim time, rising) of ``truth``; the GNSS receivers
        record it too (:attr:`gps`: ``gps.due(t_ns)``, ``gps.fix(t_ns)``). A vehicle outside
        the ISA's layers (-5 km to 20 km), or of unknown height, reads NaN on its barometer,
        pitot and temperature: an edge never sends those."""
        spec = self.spec
        table = truth.table
        self.gps.record(t_ns, table)
        field_enu = self._field_enu(table[:, 0:3])
        dt = 1.0 / spec.rate_hz if self._last_ns is None else max(
            (t_ns - self._last_ns) / 1e9, 1e-6)
        noise = self._no_noise if self._rng is None else self._rng.standard_normal((self.n, 17))
        out = np.empty((self.n, 14))
        sample_into(table, field_enu, noise, self._bias, self._white, self._walk,
                    spec.baro_noise_pa, spec.pitot_noise_pa, dt, out)
        self._last_ns = int(t_ns)
        return SensorReadings(t_ns=int(t_ns), table=out)

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
