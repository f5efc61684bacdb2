"""SB-XC glider of seed 002: polar sink, coordinated turn, and one kinematic step.

Elementwise over arrays of any common shape (typically (B, N): B runs, N gliders); per-run
parameters come as arrays broadcastable to that shape (e.g. (B, 1)) or scalars. Order within the
step (``agentControl_Unified.m``, spec §3.3): new speed and bank from the commands, then the
coordinated-turn rate with the *new* speed, the sink at the new speed and bank, position advanced
along the *old* heading with the new speed, then the heading. The arithmetic is that of
:mod:`sim_core.soaring.kernels` (the swarm's own), so these functions give the swarm's bits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.soaring import kernels

__all__ = ["GliderStep", "accel_to_command", "glider_step", "sink_rate"]

F8 = NDArray[np.float64]


def flat(*values: ArrayLike) -> tuple[tuple[int, ...], list[F8]]:
    """Broadcast ``values`` to one shape; return it and each value as a new flat float64 array
    (writable and contiguous, so the kernels see one array type)."""
    arrs = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in values))
    return arrs[0].shape, [np.array(a, dtype=np.float64).ravel() for a in arrs]


def sink_rate(speed: ArrayLike, bank: ArrayLike, A: ArrayLike, B: ArrayLike, C: ArrayLike) -> F8:
    """Polar sink, m/s (< 0 = sinking): (A v² + B v + C) / sqrt(cos φ).

    speed v in m/s, bank φ in rad (|φ| < π/2).
    """
    shape, (v, b, a, bb, c) = flat(speed, bank, A, B, C)
    return np.asarray(kernels.sink_many(v, b, a, bb, c)).reshape(shape)


def accel_to_command(
    ax: ArrayLike,
    ay: ArrayLike,
    heading: ArrayLike,
    speed: ArrayLike,
    *,
    dt: float,
    g: ArrayLike,
    thermal_bank_factor: ArrayLike,
    updraft: ArrayLike,
    cos_sin: tuple[ArrayLike, ArrayLike] | None = None,
) -> tuple[F8, F8]:
    """The seed's desired planar acceleration → (bank_cmd rad, airspeed_cmd m/s).

    a_f = a·f̂ (f̂ = heading unit vector); a_c = sign((f̂ × a)_z)·sqrt(‖a‖² − a_f²), 0 if
    ‖a‖ − |a_f| < 1e−6; airspeed_cmd = v + a_f·dt/10; bank_cmd = atan(a_c/g) +
    thermalBankFactor·w·sign(atan(a_c/g)). Components of a beyond ±1e100 m/s² (or infinite)
    are clipped and NaN taken as 0, so the commands stay finite. Limits are applied by
    :func:`glider_step`. ``cos_sin``: (cos ψ, sin ψ) if the caller has them already.
    """
    shape, (x, y, h, v, gg, tbf, w) = flat(ax, ay, heading, speed, g, thermal_bank_factor,
                                          updraft)
    if cos_sin is None:
        c, s = kernels.cos_sin(h)
    else:
        _, (c, s) = flat(np.broadcast_to(cos_sin[0], shape), np.broadcast_to(cos_sin[1], shape))
    out = np.asarray(kernels.command_many(x, y, c, s, v, float(dt), gg, tbf, w))
    return out[1].reshape(shape), out[0].reshape(shape)


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


#: Law columns of the parameter table that one glider step reads, in :func:`glider_step`'s
#: keyword order after ``g``.
_STEP_PARAMS = (
    kernels.P_V_MIN, kernels.P_V_MAX, kernels.P_B_MIN, kernels.P_B_MAX, kernels.P_SINK_A,
    kernels.P_SINK_B, kernels.P_SINK_C, kernels.P_CEIL, kernels.P_FLOOR, kernels.P_BANK_RATE,
    kernels.P_SPEED_RATE,
)


def glider_step(
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    heading: ArrayLike,
    bank: ArrayLike,
    speed: ArrayLike,
    bank_cmd: ArrayLike,
    airspeed_cmd: ArrayLike,
    updraft: ArrayLike,
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
    cos_sin: tuple[ArrayLike, ArrayLike] | None = None,
) -> GliderStep:
    """Fly one step of dt seconds from the commands (seed §3.3).

    speed ← clip(rate-limited airspeed_cmd, speed_min, speed_max); bank ← clip(rate-limited
    bank_cmd, bank_min, bank_max); ω = g·tan(bank)/speed; vz = sink(speed, bank) + updraft;
    (x, y) += speed·(cos ψ_old, sin ψ_old)·dt; z += vz·dt clamped to the ceiling, and to the floor
    unless it reached z <= 0 (ground: then x, y, z, heading and speed keep their old values;
    the caller keeps its old vz and omega); ψ += ω·dt. Rate limits are in rad/s and m/s²
    (``inf`` = none, the seed). ``cos_sin``: (cos ψ, sin ψ) if the caller has them already.
    """
    A, B, C = sink_abc
    params = (speed_min, speed_max, bank_min, bank_max, A, B, C, ceiling, floor, bank_rate_max,
              speed_rate_max)
    shape, cols = flat(x, y, z, heading, bank, speed, airspeed_cmd, bank_cmd, updraft, g,
                       *params)
    if cos_sin is None:
        c, s = kernels.cos_sin(cols[3])
    else:
        _, (c, s) = flat(np.broadcast_to(cos_sin[0], shape), np.broadcast_to(cos_sin[1], shape))
    par = np.zeros((cols[0].shape[0], len(kernels.PAR)))
    par[:, kernels.P_G] = cols[9]
    for col, values in zip(_STEP_PARAMS, cols[10:], strict=True):
        par[:, col] = values
    X = np.stack([*cols[:9], c, s])
    out = np.asarray(kernels.fly_many(X, float(dt), par))
    ground = out[8] != 0.0

    def kept(new: F8, old: F8) -> F8:
        return np.where(ground, old, new).reshape(shape)

    return GliderStep(
        x=kept(out[0], cols[0]),
        y=kept(out[1], cols[1]),
        z=kept(out[2], cols[2]),
        heading=kept(out[3], cols[3]),
        bank=out[6].reshape(shape),
        speed=kept(out[5], cols[5]),
        omega=out[4].reshape(shape),
        vz=out[7].reshape(shape),
        ground=ground.reshape(shape),
    )
