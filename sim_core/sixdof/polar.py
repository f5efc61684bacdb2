"""A JSBSim glider's still-air polar, measured by flying it, in ArduPilot's soaring form.

ArduPilot's soaring code (``SOAR_POLAR_CD0``, ``SOAR_POLAR_B``, ``SOAR_POLAR_K``) models the
sink at equivalent airspeed V and bank φ as ``V·(CD0/CL + B·CL/cos²φ)`` with ``CL = K/V²`` and
``K = 2·m·g/(ρ0·S)`` (ρ0 = 1.225 kg/m³). :func:`measure_glides` flies the glider wings level on
fixed elevators until its phugoid has died out and averages each steady glide;
:func:`fit_polar` takes K from the aircraft's mass and wing area and fits CD0 and B to those
glides by least squares; :func:`polar_sink` evaluates the result.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from sim_core.sixdof.model import SixDofGliders, SixDofSpec

__all__ = ["RHO0", "Glide", "SoarPolar", "fit_polar", "measure_glides", "polar_sink"]

#: ArduPilot's sea-level density for equivalent airspeed, kg/m³
RHO0 = 1.225
_G = 9.80665


@dataclass(frozen=True, slots=True)
class Glide:
    """One steady glide: ``elevator`` held, true ``airspeed`` and ``sink`` m/s (positive
    down), ``glide_ratio`` (ground distance per height lost), air ``density`` kg/m³."""

    elevator: float
    airspeed: float
    sink: float
    glide_ratio: float
    density: float


@dataclass(frozen=True, slots=True)
class SoarPolar:
    """ArduPilot's ``SOAR_POLAR_CD0``, ``SOAR_POLAR_B``, ``SOAR_POLAR_K`` (m²/s²) and the
    aircraft's ``mass`` kg and ``wing_area`` m² behind K."""

    cd0: float
    b: float
    k: float
    mass: float
    wing_area: float

    @property
    def best_glide_ratio(self) -> float:
        """The polar's maximum L/D, ``1 / (2·sqrt(CD0·B))``."""
        return 1.0 / (2.0 * math.sqrt(self.cd0 * self.b))


def measure_glides(spec: SixDofSpec, elevators: Sequence[float], *, height_m: float = 1500.0,
                   settle_s: float = 120.0, average_s: float = 20.0,
                   dt: float = 0.01) -> tuple[list[Glide], float, float]:
    """Steady still-air glides of ``spec``'s aircraft, one per elevator (normalised, held
    with wings level), from ``height_m``; the averages of the last ``average_s`` after
    ``settle_s`` (sampled every fifth step of ``dt``). Returns the glides and the aircraft's
    mass (kg) and wing area (m²)."""
    glides = []
    mass = area = math.nan
    for de in elevators:
        g = SixDofGliders([replace(spec)], np.array([[0.0, 0.0, height_m]]), np.zeros(1))
        u = np.array([[0.0, float(de), 0.0, 0.0]])

        def still(xy: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.zeros(xy.shape[1])

        for _ in range(round(settle_s / dt)):
            g.step(dt, u, still)
        v, s, h = [], [], []
        for k in range(round(average_s / dt)):
            g.step(dt, u, still)
            if k % 5:
                continue
            o = g.outputs()
            v.append(o.airspeed[0])
            s.append(-o.velocity[0, 2])
            h.append(math.hypot(o.velocity[0, 0], o.velocity[0, 1]))
        mass, area, rho = g.mass_area_density()[0]
        glides.append(Glide(float(de), float(np.mean(v)), float(np.mean(s)),
                            float(np.mean(h) / np.mean(s)), float(rho)))
    return glides, float(mass), float(area)


def fit_polar(glides: Sequence[Glide], mass: float, wing_area: float) -> SoarPolar:
    """ArduPilot's polar through ``glides`` (at least two): K from ``mass`` and
    ``wing_area``, CD0 and B by least squares on the sinks at equivalent airspeed."""
    if len(glides) < 2:
        raise ValueError(f"at least two glides expected, got {len(glides)}")
    k = 2.0 * mass * _G / (RHO0 * wing_area)
    scale = np.sqrt(np.array([gl.density for gl in glides]) / RHO0)
    v = np.array([gl.airspeed for gl in glides]) * scale
    sink = np.array([gl.sink for gl in glides]) * scale
    cl = k / v**2
    a = np.stack([v / cl, v * cl], axis=1)
    (cd0, b), *_ = np.linalg.lstsq(a, sink, rcond=None)
    return SoarPolar(float(cd0), float(b), float(k), float(mass), float(wing_area))


def polar_sink(polar: SoarPolar, airspeed: float, density: float = RHO0,
               bank: float = 0.0) -> float:
    """The polar's sink m/s at true ``airspeed`` m/s in air of ``density``, at ``bank`` rad."""
    scale = math.sqrt(density / RHO0)
    v = airspeed * scale
    cl = polar.k / v**2
    return v * (polar.cd0 / cl + polar.b * cl / math.cos(bank) ** 2) / scale
