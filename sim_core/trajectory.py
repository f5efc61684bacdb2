"""Timed kinematic paths: a :class:`Trajectory` sampled by interpolation, many at once by
:func:`sample_paths`.

Linear interpolation of position, bank and airspeed, shortest-arc interpolation of heading,
spherical interpolation of a logged attitude; times past the end wrap (``loop``) or clamp. The
same paths drive scene vehicles (:mod:`sim_core.scene`), trajectory replay and the path states
of :mod:`sim_core.flight`; flight logs are read into them by ``hil_bridge.recording.logs``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.pose import quat_normalize, quat_slerp

__all__ = ["Trajectory", "sample_paths"]

FloatArray = NDArray[np.float64]


def _wrap_pi(a: FloatArray) -> FloatArray:
    """Angles wrapped to [-pi, pi)."""
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


@dataclass(frozen=True, slots=True, eq=False)
class Trajectory:
    """A timed kinematic path, sampled by interpolation.

    Arrays (K >= 2 samples): ``t`` (K,) s strictly increasing; ``xyz`` (K, 3) m ENU; ``heading``
    (K,) rad from +x towards +y; ``bank`` (K,) rad; ``airspeed`` (K,) m/s. ``loop``: times past
    the end wrap around to the start (otherwise they clamp to the last sample). ``quat``
    (K, 4), optional: the logged attitude, world-from-body ``[w, x, y, z]`` (ENU/FLU,
    :mod:`sim_core.pose`), sampled by :meth:`attitude`.
    """

    t: FloatArray
    xyz: FloatArray
    heading: FloatArray
    bank: FloatArray
    airspeed: FloatArray
    loop: bool = False
    quat: FloatArray | None = None
    _table: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        k = t.shape[0] if t.ndim == 1 else -1
        if k < 2:
            raise ValueError(f"t: expected a 1-D array of at least 2 times, got shape {t.shape}")
        shapes = {"xyz": (k, 3), "heading": (k,), "bank": (k,), "airspeed": (k,)}
        if self.quat is not None:
            shapes["quat"] = (k, 4)
        arrays = {"t": t}
        for name, shape in shapes.items():
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
            arrays[name] = arr
        for name, arr in arrays.items():
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{name}: contains non-finite values")
            object.__setattr__(self, name, arr)
        if self.quat is not None:
            object.__setattr__(self, "quat", quat_normalize(arrays["quat"]))
        if not np.all(np.diff(t) > 0):
            bad = int(np.argmin(np.diff(t) > 0)) + 1
            raise ValueError(f"t: expected strictly increasing times, t[{bad}] = {t[bad]}")
        object.__setattr__(self, "_table", np.column_stack([
            arrays["xyz"], np.unwrap(arrays["heading"]), arrays["bank"], arrays["airspeed"]]))

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def sample(self, t: float | FloatArray) -> dict[str, FloatArray]:
        """Interpolated state at time(s) ``t`` (s, shape (Q,) or scalar).

        Returns arrays shaped like ``t``: ``x, y, z, heading`` (wrapped to [-pi, pi)),
        ``bank, airspeed`` and ``vz`` (m/s, the slope of z over the containing segment).
        """
        tq = np.asarray(t, dtype=np.float64)
        out = sample_paths((self,), tq.reshape(1, -1))
        return {k: v.reshape(tq.shape) for k, v in out.items()}

    def attitude(self, t: float | FloatArray) -> FloatArray | None:
        """Logged attitude at time(s) ``t``: shape ``t.shape + (4,)``, spherical interpolation
        between the neighbouring samples (times clamp or wrap as in :meth:`sample`); None when
        the trajectory carries no attitude."""
        if self.quat is None:
            return None
        tq = np.asarray(t, dtype=np.float64)
        if self.loop:
            tq = self.t[0] + np.mod(tq - self.t[0], self.duration)
        else:
            tq = np.clip(tq, self.t[0], self.t[-1])
        seg = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self) - 2)
        f = (tq - self.t[seg]) / (self.t[seg + 1] - self.t[seg])
        return quat_slerp(self.quat[seg], self.quat[seg + 1], f)

    @classmethod
    def from_path(
        cls,
        xyz: FloatArray,
        heading: FloatArray | None,
        *,
        speed_mps: float,
        loop: bool = True,
    ) -> Trajectory:
        """Time a geometric path (K, 3) at constant ``speed_mps`` (arc length / speed).

        ``heading`` None: the direction of travel of each segment (the last sample repeats the
        last segment's; on a ``loop``, whose last sample is the instant it wraps to the first,
        the first segment's). Bank is the coordinated-turn bank ``atan(v * dpsi/dt / g)`` of
        the timed path, the heading rate a central difference; on a ``loop`` the neighbours
        are periodic (before the first sample comes the last but one, after the last the
        second), so the join banks as any other sample does.
        """
        p = np.asarray(xyz, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 2:
            raise ValueError(f"xyz: expected shape (K>=2, 3), got {p.shape}")
        if not speed_mps > 0:
            raise ValueError(f"speed_mps: expected > 0, got {speed_mps}")
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        keep = np.concatenate([[True], seg > 1e-9])
        p = p[keep]
        seg = seg[seg > 1e-9]
        t = np.concatenate([[0.0], np.cumsum(seg)]) / speed_mps
        if heading is None:
            d = np.diff(p[:, :2], axis=0)
            h = np.arctan2(d[:, 1], d[:, 0])
            hdg = np.concatenate([h, h[:1] if loop else h[-1:]])
        else:
            hdg = np.asarray(heading, dtype=np.float64)[keep]
        psi = np.unwrap(hdg)
        if loop:
            turn, period = psi[-1] - psi[0], t[-1] - t[0]
            rate = np.gradient(np.concatenate([[psi[-2] - turn], psi, [psi[1] + turn]]),
                               np.concatenate([[t[-2] - period], t, [t[1] + period]]))[1:-1]
        else:
            rate = np.gradient(psi, t)
        bank = np.arctan(speed_mps * rate / 9.81)
        return cls(t, p, hdg, bank, np.full(t.shape, float(speed_mps)), loop=loop)


def sample_paths(trajs: Sequence[Trajectory], t: ArrayLike) -> dict[str, FloatArray]:
    """Trajectory ``trajs[v]`` at its own times ``t[v]`` (shape (V, Q), s), all at once: the
    interpolation of :meth:`Trajectory.sample` (``np.interp``'s, value for value), arrays
    (V, Q) ``x, y, z, heading, bank, airspeed, vz``."""
    tq = np.asarray(t, dtype=np.float64)
    if tq.ndim != 2 or tq.shape[0] != len(trajs):
        raise ValueError(f"t: expected shape ({len(trajs)}, Q), got {tq.shape}")
    # the wrapping for every vehicle at once; per vehicle only its segment lookup and gather
    # (no copy of its table: a logged path may hold many thousand rows)
    t_first = np.array([[traj.t[0]] for traj in trajs])
    t_last = np.array([[traj.t[-1]] for traj in trajs])
    loops = np.array([[traj.loop] for traj in trajs])
    x = np.where(loops, t_first + np.mod(tq - t_first, t_last - t_first),
                 np.minimum(np.maximum(tq, t_first), t_last))
    a, b = np.empty((*tq.shape, 6)), np.empty((*tq.shape, 6))  # (V, Q, 6)
    ta, tb = np.empty(tq.shape), np.empty(tq.shape)
    for v, traj in enumerate(trajs):
        j = np.minimum(np.maximum(traj.t.searchsorted(x[v], side="right") - 1, 0), len(traj) - 2)
        a[v], b[v] = traj._table[j], traj._table[j + 1]
        ta[v], tb[v] = traj.t[j], traj.t[j + 1]
    slope = (b - a) / (tb - ta)[..., None]
    val = np.where((x == tb)[..., None], b, slope * (x - ta)[..., None] + a)
    return {
        "x": val[..., 0], "y": val[..., 1], "z": val[..., 2], "heading": _wrap_pi(val[..., 3]),
        "bank": val[..., 4], "airspeed": val[..., 5], "vz": slope[..., 2],
    }
