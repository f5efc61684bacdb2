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

__all__ = [
    "STATE_ROWS",
    "GliderStep",
    "accel_to_command",
    "command",
    "fly",
    "glider_step",
    "limits",
    "scalar_if_uniform",
    "sink_rate",
]

F8 = NDArray[np.float64]
ArrayLike = F8 | float

def scalar_if_uniform(a: NDArray[np.generic]) -> float | F8:
    """A per-run parameter column (B, 1) as a Python float when every run has the same value
    (numpy's scalar loops are faster and give the same float64 results), else as is."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.size and bool(np.all(arr == arr.flat[0])):
        return float(arr.flat[0])
    return arr


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
    ``cos_sin``: (cos ψ, sin ψ) if the caller has them already. Evaluated by :func:`command`.
    """
    fx, fy = (np.cos(heading), np.sin(heading)) if cos_sin is None else cos_sin
    ins = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (ax, ay, fx, fy, speed, updraft))
    )
    out = np.empty((2, *ins[0].shape))
    command(out, np.stack(ins[:2]), np.stack(ins[2:4]), ins[4], dt=dt, g=g,
            thermal_bank_factor=thermal_bank_factor, updraft=ins[5])
    return out[1], out[0]


def command(
    out: F8,
    a: F8,
    cos_sin: F8,
    speed: F8,
    *,
    dt: float,
    g: ArrayLike,
    thermal_bank_factor: ArrayLike,
    updraft: ArrayLike,
) -> None:
    """:func:`accel_to_command` on stacked rows: a (2, ...) = (ax, ay) m/s², cos_sin (2, ...)
    of the heading, speed m/s; writes out (2, ...) = (airspeed_cmd m/s, bank_cmd rad)."""
    norm = np.hypot(a[0], a[1])
    if not (norm <= A_MAX).all():
        a = np.clip(np.nan_to_num(a, posinf=A_MAX, neginf=-A_MAX), -A_MAX, A_MAX)
        norm = np.hypot(a[0], a[1])
    p = a * cos_sin  # (ax·fx, ay·fy)
    a_f = p[0] + p[1]
    small = norm - np.abs(a_f) < 1e-6
    a_c = np.where(small, 0.0, np.sqrt(np.maximum(norm * norm - a_f * a_f, 0.0)))
    np.multiply(a[::-1], cos_sin, out=p)  # (ay·fx, ax·fy)
    a_c *= np.sign(p[0] - p[1])
    v_cmd = out[0]
    np.multiply(a_f, dt, out=v_cmd)
    v_cmd /= 10.0
    v_cmd += speed
    bank = np.arctan(a_c / g)
    b_cmd = out[1]
    np.multiply(thermal_bank_factor, updraft, out=b_cmd)
    b_cmd *= np.sign(bank)
    b_cmd += bank


#: Rows of a glider state block (R, ...): what :func:`fly` writes and the swarm stores.
#: Rows VX and VY (horizontal velocity v·cos ψ, v·sin ψ) are derived each step by the swarm;
#: :func:`fly` leaves them alone. Rows VX..VZ are those the Boids kernel reads per pair.
ROW_VX, ROW_VY, ROW_X, ROW_Y, ROW_Z, ROW_VZ, ROW_HEADING, ROW_OMEGA, ROW_SPEED, ROW_BANK = range(10)
STATE_ROWS = 10


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


def _rate_limited(cmd: F8, old: F8, rate_max: ArrayLike | None, dt: float) -> F8:
    """cmd slewed towards from ``old`` by at most rate_max·dt (``inf``/None: cmd itself)."""
    if rate_max is None:
        return cmd
    lim = np.asarray(rate_max * dt)
    if np.isinf(lim).all():
        return cmd
    step = np.clip(cmd - old, -lim, lim)
    return np.where(np.isinf(lim), cmd, old + step)


def fly(
    out: F8,
    xy: F8,
    z: F8,
    heading: F8,
    bank: F8,
    speed: F8,
    cmd: F8,
    updraft: ArrayLike,
    cos_sin: F8,
    *,
    dt: float,
    g: ArrayLike,
    cmd_min: F8,
    cmd_max: F8,
    sink_abc: tuple[ArrayLike, ArrayLike, ArrayLike],
    ceiling: ArrayLike,
    floor: ArrayLike,
    bank_rate_max: ArrayLike | None = None,
    speed_rate_max: ArrayLike | None = None,
) -> NDArray[np.bool_]:
    """One step of dt seconds (seed §3.3), written into ``out`` (STATE_ROWS, *shape) at the
    rows ROW_X ... ROW_BANK, *without* the ground rule: where the returned ``ground`` mask is
    True the caller keeps the old position, heading and speed (see :func:`glider_step`).

    xy (2, *shape) m and cos_sin (2, *shape) = (cos ψ, sin ψ) of the old heading; cmd
    (2, *shape) = (airspeed_cmd m/s, bank_cmd rad) as from :func:`command`, limited to
    [cmd_min, cmd_max] (each (2, ...) = (speed, bank) limits, broadcastable); the other inputs
    are broadcastable to ``shape``. ``*_rate_max``: None or ``inf`` = no rate limit.
    """
    c_v, c_b = cmd[0], cmd[1]
    v_cmd = _rate_limited(c_v, speed, speed_rate_max, dt)
    b_cmd = _rate_limited(c_b, bank, bank_rate_max, dt)
    if v_cmd is not c_v or b_cmd is not c_b:
        cmd = np.stack(np.broadcast_arrays(v_cmd, b_cmd))
    new = out[ROW_SPEED : ROW_BANK + 1]
    new[...] = np.where(cmd > cmd_max, cmd_max, np.where(cmd < cmd_min, cmd_min, cmd))
    new_speed, new_bank, omega = out[ROW_SPEED], out[ROW_BANK], out[ROW_OMEGA]
    np.tan(new_bank, out=omega)
    omega *= g
    omega /= new_speed
    A, B, C = sink_abc
    np.add(sink_rate(new_speed, new_bank, A, B, C), updraft, out=out[ROW_VZ])
    adv = new_speed * cos_sin
    adv *= dt
    np.add(xy, adv, out=out[ROW_X : ROW_Y + 1])
    nz = out[ROW_Z]
    np.multiply(out[ROW_VZ], dt, out=nz)
    np.add(z, nz, out=nz)
    below = nz < floor
    ground = below & (nz <= 0)
    nz[...] = np.where(nz > ceiling, ceiling, np.where(below, floor, nz))
    nh = out[ROW_HEADING]
    np.multiply(omega, dt, out=nh)
    np.add(heading, nh, out=nh)
    return ground


def limits(
    low: tuple[ArrayLike, ArrayLike], high: tuple[ArrayLike, ArrayLike], ndim: int = 2
) -> tuple[F8, F8]:
    """(cmd_min, cmd_max) for :func:`fly` from (speed_min, bank_min) and (speed_max, bank_max),
    each broadcastable to glider arrays of ``ndim`` dimensions (scalars, or per-run (B, 1)
    arrays for (B, N) gliders), stacked as (2, ...) arrays of 1 + ndim dimensions."""
    lo = np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in low)))
    hi = np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in high)))
    pad = (1,) * max(0, 1 + ndim - lo.ndim)
    return lo.reshape(lo.shape + pad), hi.reshape(hi.shape + pad)


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
    """Fly one step of dt seconds from the commands (seed §3.3), via :func:`fly`.

    speed ← clip(rate-limited airspeed_cmd, speed_min, speed_max); bank ← clip(rate-limited
    bank_cmd, bank_min, bank_max); ω = g·tan(bank)/speed; vz = sink(speed, bank) + updraft;
    (x, y) += speed·(cos ψ_old, sin ψ_old)·dt; z += vz·dt clamped to the ceiling, and to the floor
    unless it reached z <= 0 (ground: then x, y, z, heading and speed keep their old values;
    the caller keeps its old vz and omega); ψ += ω·dt. Rate limits are in rad/s and m/s²
    (``inf`` = none, the seed). With both limits infinite the result is bit-identical to
    the seed's update. ``cos_sin``: (cos ψ, sin ψ) if the caller has them already.
    """
    ins = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64)
          for a in (x, y, z, heading, bank, speed, bank_cmd, airspeed_cmd, updraft))
    )
    x, y, z, heading, bank, speed = ins[:6]
    ch, sh = (np.cos(heading), np.sin(heading)) if cos_sin is None else cos_sin
    out = np.zeros((STATE_ROWS, *x.shape))
    lo, hi = limits((speed_min, bank_min), (speed_max, bank_max), x.ndim)
    keep = fly(
        out, np.stack([x, y]), z, heading, bank, speed, np.stack([ins[7], ins[6]]), ins[8],
        np.stack(np.broadcast_arrays(ch, sh)), dt=dt, g=g, cmd_min=lo, cmd_max=hi,
        sink_abc=sink_abc, ceiling=ceiling, floor=floor, bank_rate_max=bank_rate_max,
        speed_rate_max=speed_rate_max,
    )
    return GliderStep(
        x=np.where(keep, x, out[ROW_X]),
        y=np.where(keep, y, out[ROW_Y]),
        z=np.where(keep, z, out[ROW_Z]),
        heading=np.where(keep, heading, out[ROW_HEADING]),
        bank=out[ROW_BANK],
        speed=np.where(keep, speed, out[ROW_SPEED]),
        omega=out[ROW_OMEGA],
        vz=out[ROW_VZ],
        ground=keep,
    )
