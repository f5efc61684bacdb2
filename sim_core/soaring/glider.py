"""SB-XC glider of seed 002: polar sink, coordinated turn, and one kinematic step.

Everything is elementwise over arrays of any common shape (typically (B, N): B runs, N gliders);
per-run parameters come as arrays broadcastable to that shape (e.g. (B, 1)).
Order within the step (``agentControl_Unified.m``, spec §3.3): new speed and bank from the
commands, then the coordinated-turn rate with the *new* speed, the sink at the new speed and
bank, position advanced along the *old* heading with the new speed, then the heading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["GliderStep", "accel_to_command", "glider_step", "sink_rate"]

F8 = NDArray[np.float64]
ArrayLike = F8 | float

#: Acceleration components beyond ±A_MAX (m/s², or infinite) are clipped to it, so ‖a‖² cannot
#: overflow (never hit in the seed's runs, whose |a| stays below 1e6).
A_MAX = 1e100


def sink_rate(speed: ArrayLike, bank: ArrayLike, A: ArrayLike, B: ArrayLike, C: ArrayLike) -> F8:
    """Polar sink, m/s (< 0 = sinking): (A v² + B v + C) / sqrt(cos φ).

    speed v in m/s, bank φ in rad (|φ| < π/2).
    """
    v = np.asarray(speed, dtype=np.float64)
    return (A * v**2 + B * v + C) / np.sqrt(np.cos(bank))


def accel_to_command(
    ax: F8,
    ay: F8,
    heading: F8,
    speed: F8,
    *,
    dt: float,
    g: ArrayLike,
    thermal_bank_factor: ArrayLike,
    updraft: ArrayLike,
    cos_sin: tuple[F8, F8] | None = None,
) -> tuple[F8, F8]:
    """The seed's desired planar acceleration → (bank_cmd rad, airspeed_cmd m/s).

    a_f = a·f̂ (f̂ = heading unit vector); a_c = sign((f̂ × a)_z)·sqrt(‖a‖² − a_f²), 0 if
    ‖a‖ − |a_f| < 1e−6; airspeed_cmd = v + a_f·dt/10; bank_cmd = atan(a_c/g) +
    thermalBankFactor·w·sign(atan(a_c/g)). Limits are applied by :func:`glider_step`.
    ``cos_sin``: (cos ψ, sin ψ) if the caller has them already.
    """
    norm = np.hypot(ax, ay)
    if not (norm <= A_MAX).all():
        ax = np.clip(np.nan_to_num(ax, posinf=A_MAX, neginf=-A_MAX), -A_MAX, A_MAX)
        ay = np.clip(np.nan_to_num(ay, posinf=A_MAX, neginf=-A_MAX), -A_MAX, A_MAX)
        norm = np.hypot(ax, ay)
    fx, fy = (np.cos(heading), np.sin(heading)) if cos_sin is None else cos_sin
    a_f = ax * fx + ay * fy
    small = norm - np.abs(a_f) < 1e-6
    a_c = np.where(small, 0.0, np.sqrt(np.maximum(norm * norm - a_f * a_f, 0.0)))
    a_c = a_c * np.sign(fx * ay - fy * ax)
    airspeed_cmd = speed + a_f * dt / 10.0
    bank = np.arctan(a_c / g)
    bank_cmd = bank + thermal_bank_factor * updraft * np.sign(bank)
    return bank_cmd, airspeed_cmd


@dataclass(slots=True)
class GliderStep:
    """Result of one kinematic step; arrays shaped like the inputs.

    x, y, z: new position m; heading rad; bank rad; speed m/s; omega rad/s (turn rate); vz m/s
    (sink + updraft); ground: True where the new z fell to or below the floor at z <= 0
    (the seed's ground death: the glider's position, heading and speeds are then not updated).
    """

    x: F8
    y: F8
    z: F8
    heading: F8
    bank: F8
    speed: F8
    omega: F8
    vz: F8
    ground: NDArray[np.bool_]


def glider_step(
    x: F8,
    y: F8,
    z: F8,
    heading: F8,
    bank: F8,
    speed: F8,
    bank_cmd: F8,
    airspeed_cmd: F8,
    updraft: F8,
    *,
    dt: float,
    g: ArrayLike,
    speed_min: ArrayLike,
    speed_max: ArrayLike,
    bank_min: ArrayLike,
    bank_max: ArrayLike,
    sink_abc: tuple[ArrayLike, ArrayLike, ArrayLike],
    ceiling: ArrayLike,
    floor: ArrayLike,
    bank_rate_max: ArrayLike = np.inf,
    speed_rate_max: ArrayLike = np.inf,
    cos_sin: tuple[F8, F8] | None = None,
) -> GliderStep:
    """Fly one step of dt seconds from the commands (seed §3.3).

    speed ← clip(rate-limited airspeed_cmd, speed_min, speed_max); bank ← clip(rate-limited
    bank_cmd, bank_min, bank_max); ω = g·tan(bank)/speed; vz = sink(speed, bank) + updraft;
    (x, y) += speed·(cos ψ_old, sin ψ_old)·dt; z += vz·dt clamped to the ceiling, and to the floor
    unless it reached z <= 0 (ground: then x, y, z, heading and speed keep their old values;
    the caller keeps its old vz and omega); ψ += ω·dt. Rate limits are in rad/s and m/s²
    (``inf`` = none, the seed). With both limits infinite the result is bit-identical to
    the seed's update. ``cos_sin``: (cos ψ, sin ψ) if the caller has them already.
    """
    lim_v = np.asarray(speed_rate_max * dt)
    v_cmd = airspeed_cmd
    if not np.isinf(lim_v).all():
        step_v = np.clip(airspeed_cmd - speed, -lim_v, lim_v)
        v_cmd = np.where(np.isinf(lim_v), airspeed_cmd, speed + step_v)
    lim_b = np.asarray(bank_rate_max * dt)
    b_cmd = bank_cmd
    if not np.isinf(lim_b).all():
        step_b = np.clip(bank_cmd - bank, -lim_b, lim_b)
        b_cmd = np.where(np.isinf(lim_b), bank_cmd, bank + step_b)
    new_speed = np.where(
        v_cmd > speed_max, speed_max, np.where(v_cmd < speed_min, speed_min, v_cmd)
    )
    new_bank = np.where(b_cmd > bank_max, bank_max, np.where(b_cmd < bank_min, bank_min, b_cmd))
    omega = np.tan(new_bank) * g / new_speed
    A, B, C = sink_abc
    vz = sink_rate(new_speed, new_bank, A, B, C) + updraft
    ch, sh = (np.cos(heading), np.sin(heading)) if cos_sin is None else cos_sin
    nx = x + new_speed * ch * dt
    ny = y + new_speed * sh * dt
    nz = z + vz * dt
    below = nz < floor
    ground = below & (nz <= 0)
    nz = np.where(nz > ceiling, ceiling, np.where(below, floor, nz))
    nh = heading + omega * dt
    keep = ground
    return GliderStep(
        x=np.where(keep, x, nx),
        y=np.where(keep, y, ny),
        z=np.where(keep, z, nz),
        heading=np.where(keep, heading, nh),
        bank=new_bank,
        speed=np.where(keep, speed, new_speed),
        omega=omega,
        vz=vz,
        ground=ground,
    )
