"""JSBSim gliders stepped in the scene's air mass, in the scene's frames (ENU world, FLU body).

:class:`SixDofGliders` holds one JSBSim ``FGFDMExec`` per vehicle. The scene's local ENU frame
(metres, z up, z = 0 the ground) is the tangent plane at ``origin`` (geodetic latitude,
longitude in degrees, height in metres of the WGS-84 ellipsoid), where JSBSim's terrain is put;
positions come back through :func:`enu_from_geodetic` (exact, WGS-84) so every
JSBSim vehicle and every other vehicle of the scene share one frame.

Controls, per vehicle ``(aileron, elevator, throttle, rudder)`` (:data:`CONTROLS`), are JSBSim's
normalised commands: aileron, elevator, rudder in [-1, 1] (JSBSim's signs: positive elevator is
trailing edge down, nose down), throttle in [0, 1] (ignored by an aircraft without engines).
Each internal step of at most ``dt_max_s`` sets JSBSim's wind to the updraft the caller gives
at the vehicle's horizontal position (``atmosphere/wind-down-fps = -w``), so a glider climbs at
the updraft minus its sink.

A vehicle that comes down (its height above JSBSim's terrain below ``-GROUND_MARGIN_M``: through
the ground, which JSBSim's contact points let a glider on its back or its wing do) or whose
state JSBSim no longer keeps finite is **down**: ``alive`` False from then on, no longer
stepped, and its outputs frozen at rest where it was last sound (its last position and
attitude, no velocity, no rates, the specific force of gravity's reaction, no airspeed).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim_core.pose import (
    enu_from_ned,
    euler_from_quat,
    flu_from_frd,
    quat_conjugate,
    quat_enu_flu_from_ned_frd,
    quat_from_euler,
    quat_rotate,
)

__all__ = [
    "CONTROLS",
    "GROUND_MARGIN_M",
    "SixDofGliders",
    "SixDofOutputs",
    "SixDofSpec",
    "enu_from_geodetic",
    "geodetic_from_enu",
]

F8 = NDArray[np.float64]

#: the columns of a controls array, in order
CONTROLS = ("aileron", "elevator", "throttle", "rudder")
_FT = 0.3048
_G = 9.80665  # m/s², standard gravity: what an accelerometer at rest reads, up
#: m below JSBSim's terrain past which a vehicle has gone through the ground: down
GROUND_MARGIN_M = 1.0
_SLUG = 14.5939029
_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3
#: the lower bounds of CONTROLS (their upper bounds are 1)
_CONTROLS_LO = np.array([-1.0, -1.0, 0.0, -1.0])
#: what :meth:`SixDofGliders.outputs` reads of each vehicle, in one pass (column order)
_OUT_PROPS = (
    "velocities/v-north-fps", "velocities/v-east-fps", "velocities/v-down-fps",
    "attitude/phi-rad", "attitude/theta-rad", "attitude/psi-rad",
    "velocities/p-rad_sec", "velocities/q-rad_sec", "velocities/r-rad_sec",
    "forces/fbx-total-lbs", "forces/fby-total-lbs", "forces/fbz-total-lbs",
    "inertia/mass-slugs", "velocities/vt-fps", "position/h-agl-ft",
    "position/lat-geod-rad", "position/long-gc-rad", "position/h-sl-meters",
)
_GEO_PROPS = _OUT_PROPS[-3:]
#: the columns a sound state has finite (velocity, attitude, rates, airspeed, position)
_SOUND_COLS = np.array([*range(9), 13, 15, 16, 17])


@dataclass(frozen=True, slots=True)
class SixDofSpec:
    """A vehicle flown by JSBSim (``vehicles[].sixdof`` of a scene).

    ``aircraft``: a JSBSim model name (its package ships ``sgs126``, the SGS 1-26 single-seat
    glider, and ``sgs233``, nose-heavy as shipped; their polars: ``echoloop ardupilot polar``,
    ``docs/ardupilot.md``). ``airspeed_mps``: the true airspeed it starts at, level, on its
    path's heading at its path's start point. ``origin``: [lat deg, lon deg, height m] of the
    scene's ENU origin. ``dt_max_s``: the longest JSBSim step.
    """

    aircraft: str = "sgs126"
    airspeed_mps: float = 20.0
    origin: tuple[float, float, float] = (47.0, 8.0, 0.0)
    dt_max_s: float = 0.0025

    def __post_init__(self) -> None:
        if not self.aircraft or "/" in self.aircraft or "\\" in self.aircraft:
            raise ValueError(f"aircraft: expected a JSBSim model name, got {self.aircraft!r}")
        if not 0 < self.airspeed_mps < 150:
            raise ValueError(f"airspeed_mps: expected 0 < speed < 150, got {self.airspeed_mps}")
        lat, lon, _ = self.origin
        if not (-89.0 <= lat <= 89.0 and -180.0 <= lon <= 180.0):
            raise ValueError(f"origin: expected [lat in [-89, 89], lon in [-180, 180], height], "
                             f"got {list(self.origin)}")
        if not 1e-4 <= self.dt_max_s <= 0.02:
            raise ValueError(f"dt_max_s: expected 1e-4 <= dt <= 0.02, got {self.dt_max_s}")


@dataclass(frozen=True, slots=True)
class SixDofOutputs:
    """Every JSBSim vehicle now, rows in construction order: ``position``, ``velocity`` (N, 3)
    m, m/s world ENU; ``quat`` (N, 4) world-from-body ENU-from-FLU; ``roll``, ``pitch``, ``yaw``
    (N,) its Z-Y-X Euler angles; ``rates`` (N, 3) body rates rad/s FLU; ``specific_force``
    (N, 3) m/s² FLU (what an accelerometer reads: +g up at rest); ``airspeed`` (N,) true
    airspeed m/s; ``geodetic`` (N, 3) JSBSim's own position: latitude, longitude deg and height
    m above the WGS-84 ellipsoid; ``alive`` (N,) False once the vehicle is down (the module
    docstring: its rows then hold it at rest where it was last sound)."""

    position: F8
    velocity: F8
    quat: F8
    roll: F8
    pitch: F8
    yaw: F8
    rates: F8
    specific_force: F8
    airspeed: F8
    geodetic: F8
    alive: NDArray[np.bool_]


def _ecef(lat: F8, lon: F8, h: F8) -> F8:
    """WGS-84 geodetic (rad, rad, m) arrays (N,) → ECEF (N, 3) m."""
    s, c = np.sin(lat), np.cos(lat)
    n = _WGS84_A / np.sqrt(1.0 - _WGS84_E2 * s * s)
    out = np.empty((len(lat), 3))  # np.stack's bookkeeping cost more than this on a tick's few
    out[:, 0] = (n + h) * c * np.cos(lon)
    out[:, 1] = (n + h) * c * np.sin(lon)
    out[:, 2] = (n * (1.0 - _WGS84_E2) + h) * s
    return out


def _enu_axes(lat0: float, lon0: float) -> F8:
    """Rows: east, north, up unit vectors (3, 3) in ECEF at (lat0, lon0) rad."""
    sl, cl, so, co = math.sin(lat0), math.cos(lat0), math.sin(lon0), math.cos(lon0)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def enu_from_geodetic(lat: F8, lon: F8, h: F8, origin: tuple[float, float, float]) -> F8:
    """Geodetic latitude, longitude (rad) and height (m) arrays (N,) → ENU (N, 3) m in the
    tangent plane at ``origin`` ([lat deg, lon deg, height m]), WGS-84."""
    lat0, lon0 = math.radians(origin[0]), math.radians(origin[1])
    p0 = _ecef(np.array([lat0]), np.array([lon0]), np.array([float(origin[2])]))[0]
    d = _ecef(np.asarray(lat, np.float64), np.asarray(lon, np.float64),
              np.asarray(h, np.float64)) - p0
    return np.asarray(d @ _enu_axes(lat0, lon0).T, dtype=np.float64)


def geodetic_from_enu(enu: F8, origin: tuple[float, float, float]) -> tuple[F8, F8, F8]:
    """ENU points (N, 3) m → geodetic (lat rad, lon rad, height m) arrays (N,), the inverse of
    :func:`enu_from_geodetic` to below a millimetre within 100 km (fixed-point steps on the
    origin's radii of curvature until the residual is below 0.1 mm, at most ten)."""
    e = np.asarray(enu, dtype=np.float64).reshape(-1, 3)
    lat0, lon0 = math.radians(origin[0]), math.radians(origin[1])
    s = math.sin(lat0)
    n_rad = _WGS84_A / math.sqrt(1.0 - _WGS84_E2 * s * s)
    m_rad = n_rad * (1.0 - _WGS84_E2) / (1.0 - _WGS84_E2 * s * s)
    lat = np.full(len(e), lat0)
    lon = np.full(len(e), lon0)
    h = np.full(len(e), float(origin[2]))
    for _ in range(10):
        r = e - enu_from_geodetic(lat, lon, h, origin)
        if np.abs(r).max(initial=0.0) < 1e-4:
            break
        lat = lat + r[:, 1] / (m_rad + h)
        lon = lon + r[:, 0] / ((n_rad + h) * math.cos(lat0))
        h = h + r[:, 2]
    return lat, lon, h


class SixDofGliders:
    """JSBSim vehicles, one per spec, started level through the air at ``airspeed_mps`` from
    ``starts`` (N, 3) ENU m on ``headings`` (N,) rad (ENU: from +x towards +y), already moving
    with the air mass of ``updraft(xy (2, N)) → (N,)`` m/s (still air when None), so a glider
    that starts in a thermal is not jolted by it."""

    def __init__(self, specs: Sequence[SixDofSpec], starts: F8, headings: F8,
                 updraft: Callable[[F8], F8] | None = None) -> None:
        import jsbsim

        jsbsim.FGJSBBase().debug_lvl = 0  # no banner or model report on stdout
        self.specs = tuple(specs)
        starts = np.asarray(starts, dtype=np.float64).reshape(len(self.specs), 3)
        self._fdm: list[Any] = []
        self._controls = np.zeros((len(self.specs), len(CONTROLS)))
        self._alive = np.ones(len(self.specs), dtype=bool)
        self._last: SixDofOutputs | None = None  # the last outputs, for a vehicle down
        origins = np.radians([[sp.origin[0], sp.origin[1]] for sp in self.specs]).reshape(-1, 2)
        self._origin_ecef = _ecef(origins[:, 0], origins[:, 1],
                                  np.array([sp.origin[2] for sp in self.specs], dtype=np.float64))
        self._origin_axes = np.array([_enu_axes(la, lo) for la, lo in origins]).reshape(-1, 3, 3)
        w0 = np.zeros(len(self.specs)) if updraft is None else np.asarray(
            updraft(starts[:, :2].T), dtype=np.float64).reshape(len(self.specs))
        for spec, start, psi, w in zip(self.specs, starts, np.asarray(headings, np.float64), w0,
                                       strict=True):
            fdm = jsbsim.FGFDMExec(None)
            fdm.set_debug_level(0)
            if not fdm.load_model(spec.aircraft):
                raise ValueError(f"aircraft: JSBSim has no model {spec.aircraft!r}")
            fdm.set_dt(spec.dt_max_s)
            lat, lon, h = geodetic_from_enu(start[None], spec.origin)
            fdm["ic/terrain-elevation-ft"] = spec.origin[2] / _FT
            fdm["ic/lat-geod-rad"] = float(lat[0])
            fdm["ic/long-gc-rad"] = float(lon[0])
            fdm["ic/h-sl-ft"] = float(h[0]) / _FT
            fdm["ic/vt-fps"] = spec.airspeed_mps / _FT
            fdm["ic/psi-true-rad"] = (math.pi / 2 - float(psi)) % (2 * math.pi)
            fdm["ic/gamma-rad"] = 0.0
            fdm["atmosphere/wind-down-fps"] = -float(w) / _FT
            if not fdm.run_ic():
                raise ValueError(f"aircraft {spec.aircraft!r}: JSBSim refused the start state")
            self._fdm.append(fdm)

    def __len__(self) -> int:
        return len(self._fdm)

    def step(self, dt: float, controls: F8, updraft: Callable[[F8], F8] | None,
             active: NDArray[np.bool_] | None = None) -> None:
        """Fly every vehicle (or those ``active``) ``dt`` s on ``controls`` (N, 4)
        (:data:`CONTROLS`, clipped to their ranges), in JSBSim steps of at most each spec's
        ``dt_max_s``; ``updraft(xy (2, N)) → (N,)`` m/s is asked once per step (None: the air
        keeps the vertical wind it has, still air from a start without updraft)."""
        u = np.asarray(controls, dtype=np.float64).reshape(len(self), len(CONTROLS))
        # NaN flies neutral, ±inf the range's ends (np.clip(np.nan_to_num(u)) at a fifth of
        # its cost on a tick's few vehicles)
        self._controls = np.minimum(np.maximum(np.where(np.isnan(u), 0.0, u), _CONTROLS_LO), 1.0)
        on = self._alive if active is None else self._alive & np.asarray(active, dtype=bool)
        n = max((math.ceil(dt / s.dt_max_s - 1e-9) for s in self.specs), default=0)
        if n == 0 or dt <= 0:
            return
        for k, fdm in enumerate(self._fdm):
            if on[k]:
                fdm.set_dt(dt / n)
                a, e, t, r = self._controls[k]
                fdm["fcs/aileron-cmd-norm"] = a
                fdm["fcs/elevator-cmd-norm"] = e
                fdm["fcs/rudder-cmd-norm"] = r
                if fdm.get_propulsion().get_num_engines():
                    fdm["fcs/throttle-cmd-norm"] = t
        for _ in range(n):
            w = None if updraft is None else np.asarray(
                updraft(self._positions()[:, :2].T), dtype=np.float64)
            for k, fdm in enumerate(self._fdm):
                if on[k]:
                    if w is not None:
                        fdm["atmosphere/wind-down-fps"] = -float(w[k]) / _FT
                    fdm.run()

    def mass_area_density(self) -> F8:
        """Per vehicle (N, 3): mass kg, wing area m², air density kg/m³ where it flies."""
        return np.array([[fdm["inertia/mass-slugs"] * _SLUG, fdm["metrics/Sw-sqft"] * _FT**2,
                          fdm["atmosphere/rho-slugs_ft3"] * _SLUG / _FT**3]
                         for fdm in self._fdm]).reshape(-1, 3)

    def _geodetic(self) -> F8:
        """Every vehicle's latitude, longitude (rad) and height (m) (N, 3)."""
        return np.array([[fdm[p] for p in _GEO_PROPS] for fdm in self._fdm]).reshape(-1, 3)

    def _positions(self, geo: F8 | None = None) -> F8:
        """Every vehicle's ENU position (N, 3) m (from ``geo``, :meth:`_geodetic`, if given)."""
        geo = self._geodetic() if geo is None else geo
        d = _ecef(geo[:, 0], geo[:, 1], geo[:, 2]) - self._origin_ecef
        return np.asarray(np.einsum("nij,nj->ni", self._origin_axes, d), dtype=np.float64)

    def outputs(self) -> SixDofOutputs:
        """Every vehicle's state now (:class:`SixDofOutputs`); a vehicle down is held at rest
        where it was last sound (the module docstring)."""
        raw = np.array([[fdm[p] for p in _OUT_PROPS] for fdm in self._fdm]).reshape(
            -1, len(_OUT_PROPS))
        v_ned, euler, pqr = raw[:, 0:3], raw[:, 3:6].copy(), raw[:, 6:9]
        f_frd = raw[:, 9:12] / raw[:, 12:13]
        vt, agl, geo = raw[:, 13], raw[:, 14] * _FT, raw[:, 15:18].copy()
        sound = np.isfinite(raw[:, _SOUND_COLS]).all(axis=1) & np.isfinite(f_frd).all(axis=1)
        sound &= agl >= -GROUND_MARGIN_M
        if not sound.all():
            self._alive &= sound
            euler[~sound] = 0.0  # a row not sound is replaced below: keep its maths finite
            geo[~sound] = 0.0
        pos = self._positions(geo)
        geodetic = geo.copy()
        geodetic[:, :2] = np.degrees(geo[:, :2])
        quat = quat_enu_flu_from_ned_frd(quat_from_euler(euler[:, 0], euler[:, 1], euler[:, 2]))
        roll, pitch, yaw = euler_from_quat(quat)
        out = SixDofOutputs(
            position=pos, velocity=enu_from_ned(v_ned) * _FT, quat=quat, roll=roll,
            pitch=pitch, yaw=yaw, rates=flu_from_frd(pqr),
            specific_force=flu_from_frd(f_frd) * _FT, airspeed=vt * _FT,
            alive=self._alive.copy(),
            geodetic=geodetic,
        )
        down = ~self._alive
        if down.any():
            out = self._at_rest(out, down)
        self._last = out
        return out

    def _at_rest(self, out: SixDofOutputs, down: NDArray[np.bool_]) -> SixDofOutputs:
        """``out`` with the rows ``down`` held at rest where the previous outputs had them."""
        last = out if self._last is None else self._last
        fields: dict[str, Any] = {}
        for name in ("position", "quat", "roll", "pitch", "yaw", "geodetic"):
            now, was = getattr(out, name), getattr(last, name)
            fields[name] = np.where(down.reshape(-1, *([1] * (now.ndim - 1))), was, now)
        rest = np.zeros((int(down.sum()), 3))
        up = quat_rotate(quat_conjugate(fields["quat"][down]), np.array([0.0, 0.0, _G]))
        for name, value in (("velocity", rest), ("rates", rest), ("specific_force", up),
                            ("airspeed", 0.0)):
            a = getattr(out, name).copy()
            a[down] = value
            fields[name] = a
        return SixDofOutputs(alive=out.alive, **fields)
