"""Parameters, beams and the echo result of :mod:`sim_core.sonar` (frozen data only).

Defaults are those of ``docs/spec/echo_model.md``; every opt-in physics switch defaults to *off*, so
``EchoParams()`` is exactly the ``reference`` model. Units: SI (m, s, Hz, rad, degC, kPa).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.pose import cross
from sim_core.sonar.seedbeam import BeamLookup

__all__ = ["Beam", "Call", "Ear", "Echo", "EchoParams", "FrequencyGrid"]

#: relative slack on f*N/fs being an integer (floating-point band edges such as fs/N)
BIN_TOLERANCE = 1e-12
#: 10^(-3/20): the one-way -3 dB level that defines the beamwidth.
MINUS_3DB = 0.7079
#: BW/2 = SIGMA_FACTOR * sigma for a Gaussian beam (sqrt(2 ln(1/0.7079))).
SIGMA_FACTOR = math.sqrt(2.0 * math.log(1.0 / MINUS_3DB))


def _finite_vec3(value: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return arr


@dataclass(frozen=True, slots=True)
class Call:
    """Emitted call whose spectrum shapes the echo (``echo = call * impulse response``).

    ``kind``: ``"fm"`` — a linear FM sweep from ``f_start`` to ``f_end`` over ``duration_s``;
    ``"cf-fm"`` — a horseshoe-bat call: a constant-frequency part at ``cf_hz`` lasting
    ``cf_duration_s`` followed by the FM sweep ``cf_hz -> f_end`` over ``duration_s``.
    Both carry a Hann envelope with ``taper_s`` rise/fall. Only the part of the call spectrum
    inside the model band [f_lo, f_hi] reaches the echo (widen the band to hear a CF above it).
    """

    kind: Literal["fm", "cf-fm"] = "fm"
    f_start: float = 80e3
    f_end: float = 60e3
    duration_s: float = 2e-3
    cf_hz: float = 83e3
    cf_duration_s: float = 10e-3
    taper_s: float = 0.2e-3

    def __post_init__(self) -> None:
        for name in ("f_start", "f_end", "duration_s", "cf_hz", "taper_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"Call.{name} must be > 0, got {getattr(self, name)!r}")
        if not self.cf_duration_s >= 0:
            raise ValueError(f"Call.cf_duration_s must be >= 0, got {self.cf_duration_s!r}")

    @property
    def total_s(self) -> float:
        """Length of the call in seconds."""
        return self.duration_s + (self.cf_duration_s if self.kind == "cf-fm" else 0.0)


@dataclass(frozen=True, slots=True)
class Ear:
    """One receiver of a multi-channel (e.g. binaural) sonar.

    ``offset`` is the ear position relative to the emitter in the *beam frame* (x along the
    boresight, y to the left = boresight-azimuth + 90 deg in the horizontal plane, z = x × y),
    metres. ``yaw_rad``/``pitch_rad`` turn the ear's beam axis away from the boresight (positive
    yaw towards +y of the beam frame). ``beamwidth_rad`` None means "same as the emitter".
    """

    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_rad: float = 0.0
    pitch_rad: float = 0.0
    beamwidth_rad: float | None = None

    def __post_init__(self) -> None:
        _finite_vec3(self.offset, "Ear.offset")
        if not (math.isfinite(self.yaw_rad) and math.isfinite(self.pitch_rad)):
            raise ValueError(f"Ear yaw/pitch must be finite, got {self.yaw_rad}, {self.pitch_rad}")
        if self.beamwidth_rad is not None and not 0.0 < self.beamwidth_rad < math.pi:
            raise ValueError(f"Ear.beamwidth_rad must be in (0, pi), got {self.beamwidth_rad!r}")

    @staticmethod
    def binaural(
        spacing_m: float = 0.03, splay_rad: float = math.radians(15.0)
    ) -> tuple[Ear, Ear]:
        """Left and right ears ``spacing_m`` apart, each turned ``splay_rad`` outwards."""
        half = 0.5 * spacing_m
        return (
            Ear(offset=(0.0, half, 0.0), yaw_rad=splay_rad),
            Ear(offset=(0.0, -half, 0.0), yaw_rad=-splay_rad),
        )


@dataclass(frozen=True, slots=True)
class EchoParams:
    """All model parameters (defaults = ``docs/spec/echo_model.md``); physics switches are opt-in.

    Core (reference): ``sound_speed`` m/s, band ``f_lo``..``f_hi`` Hz, sample rate ``fs`` Hz,
    ``samples`` N, gain constant ``g0``, ``spreading`` (1/r^2; None = on, off under
    ``seed2020``), selection threshold ``threshold_db`` (G), ``a_min`` m, ``r_min`` m,
    ``peak_amplitude`` (A0).

    Opt-in physics (all off by default):
    - ``absorption``: ISO 9613-1 air absorption over the two-way path, from ``temperature_c``,
      ``humidity_pct`` (relative) and ``pressure_kpa``.
    - ``speed_from_temperature``: v = 331.3 sqrt(1 + T/273.15) replaces ``sound_speed``.
    - ``platform_velocity`` (m/s, world frame): exact moving-platform two-way delay (the sonar
      keeps moving while the sound travels); ``doppler`` additionally scales frequencies
      (reference fidelity only).
    - ``call``: emitted call; the echo is the call convolved with the impulse response.
    - ``shading`` with ``shading_opacity``: nearer leaves occlude farther ones (docs/sonar.md).
    - ``near_field_cap``: |g0 L / k| <= r / 2 (a leaf cannot return more than a mirror).
    - ``ears``: receivers (e.g. :meth:`Ear.binaural`) -> one echo channel per ear.
    - ``seed2020``: parity with the seed's 2020 paper code (``Demonstration_code_for_Paper``):
      a Gaussian in raw azimuth/elevation differences read from the code's 1° grid, and no
      1/r^2. ``beam_lookup`` ("grid" or "exact": the Gaussian at each leaf's own angles) and
      ``spreading`` override its parts; unset (None) they take the paper code's values under
      ``seed2020`` and the spec's otherwise (exact, spreading on), and read back resolved
      (so ``dataclasses.replace(p, seed2020=False)`` keeps them: give ``beam_lookup="exact"``
      and ``spreading`` too). The grid exists only in the seed's az/el form; see
      :mod:`sim_core.sonar.seedbeam`.
    - ``beam_model="incident_freq"``: the horseshoe-bat beamwidth BW(f) of the seed code
      replaces the beam's fixed beamwidth at each frequency.
    - ``budget_s``: per-echo time budget of the ``realtime`` fidelity.
    """

    sound_speed: float = 340.0
    f_lo: float = 60e3
    f_hi: float = 80e3
    fs: float = 400e3
    samples: int = 24000
    g0: float = 0.2
    spreading: bool | None = None
    threshold_db: float = 20.0
    a_min: float = 1e-3
    r_min: float = 0.1
    peak_amplitude: float = 1.0
    absorption: bool = False
    temperature_c: float = 20.0
    humidity_pct: float = 50.0
    pressure_kpa: float = 101.325
    speed_from_temperature: bool = False
    platform_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    doppler: bool = False
    call: Call | None = None
    shading: bool = False
    shading_opacity: float = 0.5
    near_field_cap: bool = False
    ears: tuple[Ear, ...] = ()
    seed2020: bool = False
    beam_lookup: BeamLookup | None = None
    beam_model: Literal["fixed", "incident_freq"] = "fixed"
    budget_s: float = 5e-3
    grid: FrequencyGrid = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("sound_speed", "fs", "g0", "a_min", "r_min", "peak_amplitude", "budget_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"EchoParams.{name} must be a finite number > 0, got {value!r}")
        if isinstance(self.samples, bool) or not isinstance(self.samples, int | np.integer):
            raise ValueError(f"EchoParams.samples must be an integer, got {self.samples!r}")
        if self.samples < 2:
            raise ValueError(f"EchoParams.samples must be >= 2, got {self.samples}")
        if not math.isfinite(self.threshold_db):
            raise ValueError(f"EchoParams.threshold_db must be finite, got {self.threshold_db!r}")
        if not -273.15 < self.temperature_c < 100.0:
            raise ValueError(
                f"EchoParams.temperature_c must be in (-273.15, 100), got {self.temperature_c!r}"
            )
        if not 0.0 <= self.humidity_pct <= 100.0:
            raise ValueError(
                f"EchoParams.humidity_pct must be in [0, 100], got {self.humidity_pct!r}"
            )
        if not (math.isfinite(self.pressure_kpa) and self.pressure_kpa > 0):
            raise ValueError(f"EchoParams.pressure_kpa must be > 0, got {self.pressure_kpa!r}")
        vel = _finite_vec3(self.platform_velocity, "EchoParams.platform_velocity")
        if float(np.linalg.norm(vel)) >= 0.5 * self.speed:
            raise ValueError(
                f"EchoParams.platform_velocity {self.platform_velocity!r} must be slower than "
                f"half the speed of sound ({0.5 * self.speed:.1f} m/s)"
            )
        if not 0.0 <= self.shading_opacity <= 1.0:
            raise ValueError(
                f"EchoParams.shading_opacity must be in [0, 1], got {self.shading_opacity!r}"
            )
        if self.beam_lookup not in (None, "exact", "grid"):
            raise ValueError(
                f"EchoParams.beam_lookup must be 'exact' or 'grid', got {self.beam_lookup!r}"
            )
        if self.beam_lookup == "grid" and not self.seed2020:
            raise ValueError(
                "EchoParams.beam_lookup='grid' needs seed2020=True (the seed's 1° grid is over "
                "raw azimuth/elevation differences)"
            )
        if self.beam_lookup is None:
            object.__setattr__(self, "beam_lookup", "grid" if self.seed2020 else "exact")
        if self.spreading is None:
            object.__setattr__(self, "spreading", not self.seed2020)
        if self.beam_model not in ("fixed", "incident_freq"):
            raise ValueError(
                f"EchoParams.beam_model must be 'fixed' or 'incident_freq', got {self.beam_model!r}"
            )
        object.__setattr__(self, "grid", FrequencyGrid.from_params(self))

    @property
    def speed(self) -> float:
        """Sound speed in use (m/s): from temperature if ``speed_from_temperature``."""
        if self.speed_from_temperature:
            return 331.3 * math.sqrt(1.0 + self.temperature_c / 273.15)
        return self.sound_speed

    @property
    def selection_radius(self) -> float:
        """On-axis range cut-off r0 (m): keep r <= r0 * S1 (10 m at G = 20 dB)."""
        return 10.0 * math.sqrt(10.0 ** ((20.0 - self.threshold_db) / 20.0))

    @property
    def channels(self) -> int:
        """Number of echo channels (1 for the monostatic sonar)."""
        return max(1, len(self.ears))

    @property
    def moving(self) -> bool:
        return any(v != 0.0 for v in self.platform_velocity)


@dataclass(frozen=True, slots=True)
class FrequencyGrid:
    """The band's FFT bins, computed in exact arithmetic (spec: reject non-integer band edges).

    ``m0``, ``m1``: first/last bin index; ``count`` = m1 - m0 + 1; ``df`` = fs / N Hz.
    """

    m0: int
    m1: int
    df: float
    n: int

    @staticmethod
    def from_params(p: EchoParams) -> FrequencyGrid:
        return _grid(float(p.f_lo), float(p.f_hi), float(p.fs), int(p.samples))

    @property
    def count(self) -> int:
        return self.m1 - self.m0 + 1

    @property
    def freqs(self) -> NDArray[np.float64]:
        """Band frequencies f_k = (m0 + k) df, shape (count,), Hz."""
        return (self.m0 + np.arange(self.count, dtype=np.float64)) * self.df

    @property
    def window(self) -> NDArray[np.float64]:
        """Periodic Hann over the band bins, shape (count,) (read-only, shared)."""
        return _hann(self.count)


@functools.lru_cache(maxsize=256)
def _hann(count: int) -> NDArray[np.float64]:
    k = np.arange(count)
    out = 0.5 * (1.0 - np.cos(2.0 * np.pi * k / count))
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=256)
def _grid(f_lo: float, f_hi: float, fs: float, samples: int) -> FrequencyGrid:
    """FrequencyGrid of a band (cached: the exact rational check costs ~0.1 ms per call)."""
    n = samples
    edges = []
    for name, value in (("f_lo", f_lo), ("f_hi", f_hi)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"EchoParams.{name} must be a finite number > 0, got {value!r}")
        ratio = Fraction(value) * n / Fraction(fs)
        index = round(ratio)
        # exact in rationals; a float band edge like fs/N itself is off by an ulp
        if abs(ratio - index) > BIN_TOLERANCE * max(1, index):
            raise ValueError(
                f"EchoParams.{name}={value!r} is not a multiple of the bin spacing "
                f"fs/N = {fs / n!r} Hz (f*N/fs = {float(ratio)!r}); choose N or the band "
                "so both band edges fall on bins"
            )
        edges.append(int(index))
    m0, m1 = edges
    if not m0 < m1:
        raise ValueError(f"EchoParams band must satisfy f_lo < f_hi, got {f_lo}, {f_hi}")
    if m1 > n // 2:
        raise ValueError(
            f"EchoParams.f_hi={f_hi!r} exceeds the Nyquist frequency fs/2 = {fs / 2!r}"
        )
    return FrequencyGrid(m0=m0, m1=m1, df=fs / n, n=n)


@dataclass(frozen=True, slots=True)
class Beam:
    """A sonar pose: ``position`` (3,) m, unit ``boresight`` (3,), full -3 dB ``beamwidth_rad``."""

    position: NDArray[np.float64]
    boresight: NDArray[np.float64]
    beamwidth_rad: float

    def __init__(self, position: ArrayLike, boresight: ArrayLike, beamwidth_rad: float) -> None:
        pos = _finite_vec3(position, "Beam.position")
        axis = _finite_vec3(boresight, "Beam.boresight")
        norm = float(np.linalg.norm(axis))
        if not norm > 0.0:
            raise ValueError(f"Beam.boresight must be a non-zero vector, got {boresight!r}")
        bw = float(beamwidth_rad)
        if not (math.isfinite(bw) and 0.0 < bw < math.pi):
            raise ValueError(
                f"Beam.beamwidth_rad must be in (0, pi) (0 < BW < 180 deg), got {beamwidth_rad!r}"
            )
        pos.setflags(write=False)
        unit = axis / norm
        unit.setflags(write=False)
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "boresight", unit)
        object.__setattr__(self, "beamwidth_rad", bw)

    @staticmethod
    def from_az_el(position: ArrayLike, az: float, el: float, beamwidth: float) -> Beam:
        """Beam from boresight azimuth (from +x towards +y) and elevation (from xy-plane), rad."""
        if not (math.isfinite(az) and math.isfinite(el)):
            raise ValueError(f"Beam azimuth/elevation must be finite, got {az!r}, {el!r}")
        axis = (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
        return Beam(position, axis, beamwidth)

    @property
    def az_el(self) -> tuple[float, float]:
        """Boresight azimuth and elevation, rad."""
        b = self.boresight
        return math.atan2(float(b[1]), float(b[0])), math.asin(float(np.clip(b[2], -1.0, 1.0)))

    @property
    def sigma(self) -> float:
        """Gaussian spread sigma = (BW/2) / sqrt(2 ln(1/0.7079)), rad."""
        return 0.5 * self.beamwidth_rad / SIGMA_FACTOR

    def frame(self) -> NDArray[np.float64]:
        """Rows: forward (boresight), left, up of the beam frame, shape (3, 3)."""
        fwd = self.boresight
        left = cross(np.array([0.0, 0.0, 1.0]), fwd)
        if float(np.linalg.norm(left)) < 1e-12:
            left = np.array([0.0, 1.0, 0.0])
        left = left / np.linalg.norm(left)
        up = cross(fwd, left)
        return np.stack([fwd, left, up])


@dataclass(frozen=True, slots=True)
class Echo:
    """One synthesised echo.

    ``samples``: (N,) float64, or (C, N) for C ears; sample 0 is the emission time (t0 = 0).
    ``leaves_in_beam``: leaves kept by the selection; ``dropped``: invalid leaves removed by the
    guards (non-finite, zero normal, r < r_min). ``error_bound``: relative L2 error bound the
    fidelity ran at, None when not reported (reference: exact by definition).
    """

    samples: NDArray[np.float64]
    fs: float
    leaves_in_beam: int
    dropped: int
    fidelity: str
    error_bound: float | None = None

    @property
    def times(self) -> NDArray[np.float64]:
        """Sample times, s, shape (N,)."""
        return np.arange(self.samples.shape[-1]) / self.fs
