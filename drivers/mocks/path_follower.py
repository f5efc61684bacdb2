"""The ``path`` controller of the mock autopilot: pure pursuit along a closed route.

:class:`PathFollower` flies N vehicles along one closed polyline of waypoints (metres ENU) at a
fixed airspeed, for a low-flying sonar vehicle; :func:`figure_eight_waypoints` is its default
route, a figure-eight like the seed 000 "8" route. Used by
:class:`drivers.mocks.autopilot.MockAutopilot` (``controller: path``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PathFollower", "figure_eight_waypoints"]

F8 = NDArray[np.float64]


def _wrap(angle: F8) -> F8:
    return np.asarray((angle + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def figure_eight_waypoints(
    *, center: Sequence[float] = (0.0, 0.0), half_length_m: float = 60.0, n: int = 64
) -> F8:
    """A figure-eight route (lemniscate of Gerono), shape (n, 2) metres ENU.

    x = c_x + L sin t, y = c_y + (L/2) sin 2t over t in [0, 2 pi): two lobes of width L crossing
    at the centre, the shape of the seed 000 "8" route.
    """
    if n < 4:
        raise ValueError(f"n must be >= 4 waypoints, got {n}")
    if not half_length_m > 0:
        raise ValueError(f"half_length_m must be > 0 m, got {half_length_m}")
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.stack(
        [center[0] + half_length_m * np.sin(t), center[1] + 0.5 * half_length_m * np.sin(2 * t)],
        axis=1,
    )


class PathFollower:
    """Pure pursuit along a closed polyline for N vehicles (N == 1 is the single case).

    Each vehicle keeps a target waypoint index. Every call advances it while the target is
    closer than ``lookahead_m``, then commands the bank of the circular arc through the target
    tangent to the current heading: with heading error eta and distance d to the target,
    turn rate = 2 v sin(eta) / d, bank = atan(v * turn rate / g), clipped to +-``bank_max_rad``
    (positive bank turns towards increasing heading). Airspeed is ``airspeed_mps``.
    """

    def __init__(
        self,
        waypoints: ArrayLike,
        *,
        n_vehicles: int = 1,
        lookahead_m: float = 25.0,
        airspeed_mps: float = 10.0,
        bank_max_rad: float = math.radians(30.0),
        g: float = 9.81,
    ) -> None:
        wp = np.asarray(waypoints, dtype=np.float64)
        if wp.ndim != 2 or wp.shape[1] != 2 or wp.shape[0] < 2:
            raise ValueError(f"waypoints must have shape (M >= 2, 2), got {wp.shape}")
        if not np.all(np.isfinite(wp)):
            raise ValueError("waypoints must be finite")
        if not lookahead_m > 0:
            raise ValueError(f"lookahead_m must be > 0 m, got {lookahead_m}")
        if not airspeed_mps > 0:
            raise ValueError(f"airspeed_mps must be > 0 m/s, got {airspeed_mps}")
        if not 0 < bank_max_rad < math.pi / 2:
            raise ValueError(f"bank_max_rad must be in (0, pi/2), got {bank_max_rad}")
        self.waypoints = wp
        self.lookahead_m = float(lookahead_m)
        self.airspeed_mps = float(airspeed_mps)
        self.bank_max_rad = float(bank_max_rad)
        self.g = float(g)
        self._index: NDArray[np.intp] | None = None
        self._n = int(n_vehicles)

    @property
    def target_index(self) -> NDArray[np.intp] | None:
        """Current target waypoint per vehicle, shape (N,) (-1 until a vehicle is first
        active), None before the first call."""
        return self._index

    def command(
        self, xy: ArrayLike, heading: ArrayLike, speed: ArrayLike, active: ArrayLike = True
    ) -> tuple[F8, F8]:
        """(bank rad, airspeed m/s), each shape (N,), for positions ``xy`` (N, 2) m, heading
        (N,) rad from +x and airspeed (N,) m/s. Only ``active`` vehicles (bool, (N,) or
        scalar) advance along the route; the others' outputs are meaningless (no state)."""
        p = np.asarray(xy, dtype=np.float64).reshape(self._n, 2)
        psi = np.asarray(heading, dtype=np.float64).reshape(self._n)
        v = np.maximum(np.asarray(speed, dtype=np.float64).reshape(self._n), 0.1)
        act = np.broadcast_to(np.asarray(active, dtype=bool), (self._n,))
        wp = self.waypoints
        m = wp.shape[0]
        nearest = np.argmin(((p[:, None, :] - wp[None, :, :]) ** 2).sum(axis=2), axis=1)
        if self._index is None:
            self._index = np.full(self._n, -1, dtype=np.intp)
        idx = np.where(act & (self._index < 0), nearest, self._index).astype(np.intp)
        for _ in range(m):
            dist = np.hypot(*(wp[np.maximum(idx, 0)] - p).T)
            near = act & (dist < self.lookahead_m)
            if not near.any():
                break
            idx = np.where(near, (idx + 1) % m, idx)
        self._index = idx
        idx = np.maximum(idx, 0)
        delta = wp[idx] - p
        dist = np.maximum(np.hypot(delta[:, 0], delta[:, 1]), 1e-6)
        eta = _wrap(np.arctan2(delta[:, 1], delta[:, 0]) - psi)
        turn_rate = 2.0 * v * np.sin(eta) / dist
        bank = np.clip(np.arctan(v * turn_rate / self.g), -self.bank_max_rad, self.bank_max_rad)
        return bank, np.full(self._n, self.airspeed_mps)
