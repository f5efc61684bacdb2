"""Continuous-time flight of fixed-wing vehicles in coordinated turns: one model for every
vehicle the simulation flies (swarm gliders, commanded vehicles), and the attitude it implies.

State ``y`` has shape ``(6, *S)`` (``S`` any shape: ``(N,)`` vehicles, ``(B, N)`` runs × gliders),
rows :data:`X`, :data:`Y`, :data:`Z` (m, world ENU), :data:`HEADING` ψ (rad, from +x towards +y,
not wrapped), :data:`BANK` φ (rad, the seed's sign: positive turns towards increasing heading,
i.e. to the left, so the FLU roll is −φ) and :data:`SPEED` V (airspeed, m/s). Commands ``u``
``(2, *S)`` = (bank_cmd rad, airspeed_cmd m/s) are held over a step (zero-order hold).
The right-hand side, :meth:`FlightModel.fun`::

    ẋ = V cos ψ                       ẏ = V sin ψ
    ż = s(V, φ) + w(x, y)   (glide)     ż = 0   (hold: a powered vehicle keeping its height)
    ψ̇ = g tan φ / V                    (coordinated turn)
    φ̇ = clip((φ_c − φ) / τ_φ, −p_max, p_max)
    V̇ = clip((V_c − V) / τ_V, −a_max, a_max)

``s`` is the seed 002 SB-XC polar with its load-factor correction,
``(A V² + B V + C) / √cos φ`` (:func:`sim_core.soaring.sink_rate`), and ``w`` the updraft of the
air mass at the vehicle. As in the seed, the vehicle moves horizontally at its airspeed (at the
SB-XC's glide angle cos γ > 0.998) and a speed change costs no height. The bank and airspeed
loops are the first-order, rate-limited responses of a fixed-wing autopilot: PX4's roll loop
commands ``(φ_c − φ)/FW_R_TC`` limited to ``FW_R_RMAX`` (ArduPlane's ``RLL2SRV_TCONST`` /
``RMAX`` likewise), its TECS airspeed loop ``(V_c − V)/FW_T_TAS_TC`` limited by the energy the
airframe can trade; :class:`FlightParams` gives the defaults and their sources (docs/soaring.md).

The attitude implied by a state is that of a point mass with zero angle of attack and sideslip,
:func:`attitude`, the one derivation of it in echoloop (the flight model, path vehicles, bus
messages without an attitude, the live view and every exporter use it): yaw = ψ, roll = −φ,
and pitch = −γ (FLU: positive pitch lowers the nose), where γ = asin(s/V) is the flight-path
angle *through the air* (an updraft lifts the glider without tilting it; a ``hold`` vehicle
flies level). :func:`glide_attitude` is it for a vehicle gliding on a polar (the SB-XC's by
default), given only its heading, bank and airspeed. Body rates follow from the Euler rates
(:func:`sim_core.pose.body_rates_from_euler_rates`).

:meth:`FlightModel.step` integrates with the classical fourth-order Runge-Kutta method on
``substeps`` equal sub-steps and applies the height limits after each (the seed's rules: a
glider above the ceiling is held at it; below the floor it is held at the floor unless it
reached z <= 0: it is then *grounded*, kept at its last state and reported). The right-hand side
is continuous but not smooth where a rate limit starts to act, so the global error falls as
``h⁴`` between such instants and as ``h²`` across them (``python -m bench flight``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.frozen import readonly
from sim_core.pose import (
    body_rates_from_euler_rates,
    body_rates_from_quats,
    euler_from_quat,
    quat_from_euler,
)
from sim_core.soaring import kernels
from sim_core.soaring import warm_up as soaring_warm_up
from sim_core.soaring.glider import sink_rate
from sim_core.soaring.law import Law
from sim_core.trajectory import Trajectory, sample_paths

__all__ = [
    "BANK",
    "HEADING",
    "SPEED",
    "STATE_ROWS",
    "Attitude",
    "FlightModel",
    "FlightOutputs",
    "FlightParams",
    "PathState",
    "PathStates",
    "Updraft",
    "X",
    "Y",
    "Z",
    "attitude",
    "glide_attitude",
    "path_state",
    "path_states",
    "warm_up",
]

F8 = NDArray[np.float64]
B8 = NDArray[np.bool_]

#: rows of a flight state ``y (6, *S)``
X, Y, Z, HEADING, BANK, SPEED = range(6)
STATE_ROWS = 6

#: ``w = updraft(xy)``: vertical air speed (m/s, > 0 up) at horizontal positions ``xy (2, *S)``
Updraft = Callable[[F8], F8]


@dataclass(frozen=True, slots=True)
class FlightParams:
    """How one vehicle follows its bank and airspeed commands (scene key ``flight``).

    ``bank_tau_s`` s and ``bank_rate_max`` rad/s: first-order bank response and its rate limit
    (defaults PX4 ``FW_R_TC`` = 0.4 s and ``FW_R_RMAX`` = 70°/s; ArduPlane's
    ``RLL2SRV_TCONST`` default is 0.5 s). ``speed_tau_s`` s and ``speed_rate_max`` m/s²: the
    airspeed response (PX4 TECS ``FW_T_TAS_TC`` = 5 s; TECS limits the airspeed rate to half
    the specific energy rate the airframe gives, 0.5·g·``FW_T_SINK_MIN``/V = 0.98 m/s² at the
    SB-XC's 10 m/s with ``FW_T_SINK_MIN`` = 2 m/s). ``vertical``: ``glide`` (the SB-XC polar
    plus the updraft) or ``hold`` (a powered vehicle that keeps its height); null means the
    default of the vehicle's kind (swarm gliders glide, path vehicles hold).
    """

    bank_tau_s: float = 0.4
    bank_rate_max: float = math.radians(70.0)
    speed_tau_s: float = 5.0
    speed_rate_max: float = 1.0
    vertical: Literal["glide", "hold"] | None = None

    def __post_init__(self) -> None:
        for name in ("bank_tau_s", "bank_rate_max", "speed_tau_s", "speed_rate_max"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
        if self.vertical not in (None, "glide", "hold"):
            raise ValueError(f"vertical: expected 'glide', 'hold' or null, got {self.vertical!r}")

    @property
    def min_tau_s(self) -> float:
        """The faster of the two time constants, s."""
        return min(self.bank_tau_s, self.speed_tau_s)


@dataclass(frozen=True, slots=True)
class FlightOutputs:
    """What a flight state implies, arrays over ``S``: ``vz`` m/s (ż), ``omega`` rad/s (ψ̇),
    ``roll``, ``pitch``, ``yaw`` rad (Z-Y-X, world ENU, body FLU; yaw wrapped to [−π, π)),
    ``quat`` ``(*S, 4)`` world-from-body ``[w, x, y, z]`` and ``rates`` ``(*S, 3)`` body rates
    (p, q, r) rad/s."""

    vz: F8
    omega: F8
    roll: F8
    pitch: F8
    yaw: F8
    quat: F8
    rates: F8


def _wrap(a: F8) -> F8:
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class Attitude:
    """A world-from-body attitude, arrays over ``S``: ``roll``, ``pitch``, ``yaw`` rad (Z-Y-X,
    world ENU, body FLU; yaw wrapped to [−π, π)) and ``quat`` ``(*S, 4)`` ``[w, x, y, z]``."""

    roll: F8
    pitch: F8
    yaw: F8
    quat: F8


def attitude(heading: ArrayLike, bank: ArrayLike, airspeed: ArrayLike,
             air_vz: ArrayLike) -> Attitude:
    """The attitude of point masses in coordinated turns with zero angle of attack and sideslip
    (module docstring), arrays broadcast to ``S``: ``heading`` ψ rad, ``bank`` φ rad (the seed's
    sign: positive in a left turn), ``airspeed`` V m/s and ``air_vz`` their vertical speed
    *through the air*, m/s (> 0 up: a glider's polar sink, 0 for a vehicle holding its height,
    the climb of a path). yaw = ψ, roll = −φ, pitch = −asin(air_vz / V) (clipped to ±π/2; level
    where V <= 0, a vehicle not moving through the air)."""
    psi = np.asarray(heading, dtype=np.float64)
    phi = np.asarray(bank, dtype=np.float64)
    v = np.asarray(airspeed, dtype=np.float64)
    w = np.asarray(air_vz, dtype=np.float64)
    psi, phi, v, w = np.broadcast_arrays(psi, phi, v, w)
    moving = v > 0
    ratio = np.divide(w, v, out=np.zeros(v.shape), where=moving)
    pitch = -np.arcsin(np.clip(ratio, -1.0, 1.0))
    roll, yaw = -phi, _wrap(psi)
    return Attitude(roll=roll, pitch=pitch, yaw=yaw, quat=quat_from_euler(roll, pitch, yaw))


def glide_attitude(heading: ArrayLike, bank: ArrayLike, airspeed: ArrayLike,
                   polar: tuple[ArrayLike, ArrayLike, ArrayLike] | None = None) -> Attitude:
    """:func:`attitude` of vehicles gliding on ``polar`` ``(A, B, C)`` (default: the seed law's
    SB-XC polar, :class:`sim_core.soaring.Law`): its sink ``(A V² + B V + C) / √cos φ``
    (:func:`sim_core.soaring.sink_rate`) is their vertical speed through the air, whatever the
    updraft. This is what :meth:`FlightModel.outputs` gives a gliding state, from its heading,
    bank and airspeed alone (so for a state that carries no attitude, e.g. from a recording
    older than the attitude fields)."""
    if polar is None:
        law = Law()
        polar = (law.Sink_A, law.Sink_B, law.Sink_C)
    v = np.asarray(airspeed, dtype=np.float64)
    phi = np.asarray(bank, dtype=np.float64)
    return attitude(heading, phi, v, sink_rate(v, phi, *polar))


class FlightModel:
    """Parameters of the vehicles of one state array, as arrays broadcastable to ``S``.

    ``FlightModel(bank_tau=, bank_rate_max=, speed_tau=, speed_rate_max=, glide=, polar=(A, B,
    C), g=, ceiling=, floor=)``; :meth:`from_params` builds one from per-vehicle
    :class:`FlightParams`. Commands are assumed inside the vehicles' envelopes (callers clip).
    """

    def __init__(
        self,
        *,
        bank_tau: ArrayLike,
        bank_rate_max: ArrayLike,
        speed_tau: ArrayLike,
        speed_rate_max: ArrayLike,
        glide: ArrayLike,
        polar: tuple[ArrayLike, ArrayLike, ArrayLike],
        g: ArrayLike = 9.81,
        ceiling: ArrayLike = np.inf,
        floor: ArrayLike = 0.0,
    ) -> None:
        def arr(v: ArrayLike) -> F8:
            return np.asarray(v, dtype=np.float64)

        self.bank_tau, self.bank_rate_max = arr(bank_tau), arr(bank_rate_max)
        self.speed_tau, self.speed_rate_max = arr(speed_tau), arr(speed_rate_max)
        for name in ("bank_tau", "bank_rate_max", "speed_tau", "speed_rate_max"):
            if not np.all(getattr(self, name) > 0):
                raise ValueError(f"{name}: expected values > 0")
        self.glide: B8 = np.asarray(glide, dtype=bool)
        self.any_glide = bool(self.glide.any())
        self.A, self.B, self.C = (arr(c) for c in polar)
        self.g, self.ceiling, self.floor = arr(g), arr(ceiling), arr(floor)
        self._tables: dict[tuple[int, ...], tuple[F8, B8]] = {}
        #: longest sub-step :meth:`step` takes, s: half the fastest time constant (RK4 is
        #: stable on a first-order lag up to 2.78 τ; at τ/2 its error there is 3e-4 per step)
        self.max_substep = 0.5 * float(min(np.min(self.bank_tau), np.min(self.speed_tau)))

    @classmethod
    def from_params(
        cls,
        params: Sequence[FlightParams],
        *,
        glide: Sequence[bool],
        polar: tuple[float, float, float],
        g: float = 9.81,
        ceiling: float = np.inf,
        floor: float = 0.0,
    ) -> FlightModel:
        """Model of N vehicles (state shape ``(N,)``) from their :class:`FlightParams`;
        ``glide`` (N,) says which glide (the params' ``vertical`` already resolved)."""
        return cls(
            bank_tau=[p.bank_tau_s for p in params],
            bank_rate_max=[p.bank_rate_max for p in params],
            speed_tau=[p.speed_tau_s for p in params],
            speed_rate_max=[p.speed_rate_max for p in params],
            glide=list(glide), polar=polar, g=g, ceiling=ceiling, floor=floor,
        )

    # -- the right-hand side -----------------------------------------------------------------
    def _table(self, shape: tuple[int, ...]) -> tuple[F8, B8]:
        """The parameters broadcast to the state shape ``S`` and flattened, built once per
        shape: (:data:`~sim_core.soaring.kernels.FP_ROWS`, M) rows ``FP_*`` of the compiled
        kernels, and the glide mask (M,); both read-only, as the kernels take their inputs
        (:mod:`sim_core.frozen`)."""
        table = self._tables.get(shape)
        if table is None:
            rows = (self.bank_tau, self.bank_rate_max, self.speed_tau, self.speed_rate_max,
                    self.A, self.B, self.C, self.g, self.floor, self.ceiling)
            fp = np.stack([np.broadcast_to(r, shape).ravel() for r in rows]).astype(np.float64)
            glide = np.ascontiguousarray(np.broadcast_to(self.glide, shape).ravel())
            table = self._tables[shape] = (readonly(fp), readonly(glide))
        return table

    def _sink(self, speed: F8, bank: F8) -> F8:
        """Polar sink (< 0), m/s: (A V² + B V + C) / √cos φ, the seed's compiled kernel (that
        of :func:`sim_core.soaring.sink_rate`)."""
        shape = np.broadcast_shapes(np.shape(speed), np.shape(bank))
        fp = self._table(shape)[0]

        def flat(a: ArrayLike) -> F8:  # a contiguous copy: the kernel's compiled signature
            return np.array(np.broadcast_to(a, shape), dtype=np.float64).ravel()

        return np.asarray(kernels.sink_many(flat(speed), flat(bank), fp[kernels.FP_A],
                                            fp[kernels.FP_B], fp[kernels.FP_C])).reshape(shape)

    def derivative(self, y: F8, u: F8, w: F8 | float = 0.0) -> F8:
        """``dy/dt`` ``(6, *S)`` of states ``y (6, *S)`` under commands ``u (2, *S)`` with the
        updraft ``w`` (m/s, broadcastable to ``S``) at the vehicles: one compiled pass
        (:func:`sim_core.soaring.kernels.flight_rhs`)."""
        shape = np.broadcast_shapes(np.shape(y)[1:], np.shape(u)[1:])
        fp, glide = self._table(shape)
        yf = np.ascontiguousarray(np.broadcast_to(y, (STATE_ROWS, *shape)), dtype=np.float64)
        uf = np.ascontiguousarray(np.broadcast_to(u, (2, *shape)), dtype=np.float64)
        wf = np.ascontiguousarray(np.broadcast_to(w, shape), dtype=np.float64)
        m = glide.size
        dy = np.empty((STATE_ROWS, *shape))
        # the state as step() passes its own (a writable array), the inputs read-only
        kernels.flight_rhs(np.array(yf.reshape(STATE_ROWS, m)), readonly(uf.reshape(2, m)),
                           readonly(wf.reshape(m)), fp, glide, dy.reshape(STATE_ROWS, m))
        return dy

    def fun(self, u: ArrayLike, updraft: Updraft | None = None) -> Callable[[float, F8], F8]:
        """``fun(t, y) -> dy/dt`` for commands ``u (2, *S)`` held constant (the shape
        :func:`scipy.integrate.solve_ivp` takes, with ``y`` reshaped to ``(6, *S)``: e.g.
        ``solve_ivp(lambda t, y: fun(t, y.reshape(6, n)).ravel(), ...)``)."""
        uu = np.asarray(u, dtype=np.float64)

        def fun(t: float, y: F8) -> F8:
            w = 0.0 if updraft is None or not self.any_glide else updraft(y[X : Y + 1])
            return self.derivative(y, uu, w)

        return fun

    # -- integration -------------------------------------------------------------------------
    def step(
        self,
        y: ArrayLike,
        u: ArrayLike,
        dt: float,
        *,
        substeps: int = 1,
        updraft: Updraft | None = None,
        active: B8 | None = None,
    ) -> tuple[F8, B8]:
        """Fly ``dt`` s from ``y (6, *S)`` under commands ``u (2, *S)`` (held): ``substeps``
        RK4 steps of ``dt / substeps`` (more if that exceeds :attr:`max_substep`), the height
        limits applied after each (compiled: :func:`~sim_core.soaring.kernels.flight_rhs`,
        ``flight_stage``, ``flight_finish``; ``updraft`` is called at each stage's positions).

        ``active`` (``S``, default all): vehicles to fly; the others keep their state. Returns
        the new state and the mask of vehicles grounded during this step (z reached 0 while
        gliding; each keeps its state from just before)."""
        if substeps < 1:
            raise ValueError(f"substeps: expected >= 1, got {substeps}")
        if not dt >= 0:
            raise ValueError(f"dt: expected >= 0 s, got {dt}")
        cur = np.array(y, dtype=np.float64)
        shape = cur.shape[1:]
        live = (np.ones(shape, dtype=bool) if active is None
                else np.array(np.broadcast_to(active, shape), dtype=bool))
        grounded = np.zeros(shape, dtype=bool)
        if dt == 0 or not live.any():
            return cur, grounded
        substeps = max(substeps, math.ceil(dt / self.max_substep - 1e-9))
        fp, glide = self._table(shape)
        m = glide.size
        c = cur.reshape(STATE_ROWS, m)
        uf = readonly(np.ascontiguousarray(np.broadcast_to(np.asarray(u, dtype=np.float64),
                                                           (2, *shape))).reshape(2, m))
        lf, gf = live.reshape(m), grounded.reshape(m)
        k = np.empty((4, STATE_ROWS, m))
        stage = np.empty((STATE_ROWS, m))
        still = readonly(np.zeros(m))
        winds = updraft is not None and self.any_glide

        def rhs(state: F8, out: F8) -> None:
            w = still
            if winds:
                assert updraft is not None
                w = np.ascontiguousarray(np.broadcast_to(
                    updraft(state[X : Y + 1].reshape(2, *shape)), shape),
                    dtype=np.float64).reshape(m)
            kernels.flight_rhs(state, uf, readonly(w), fp, glide, out)

        h = dt / substeps
        for _ in range(substeps):
            rhs(c, k[0])
            kernels.flight_stage(c, h / 2, k[0], stage)
            rhs(stage, k[1])
            kernels.flight_stage(c, h / 2, k[1], stage)
            rhs(stage, k[2])
            kernels.flight_stage(c, h, k[2], stage)
            rhs(stage, k[3])
            kernels.flight_finish(c, k[0], k[1], k[2], k[3], h, fp, glide, lf, gf)
        return cur, grounded

    # -- what a state implies ----------------------------------------------------------------
    def outputs(self, y: ArrayLike, u: ArrayLike, w: ArrayLike = 0.0) -> FlightOutputs:
        """Vertical speed, turn rate and attitude of states ``y (6, *S)`` flying commands
        ``u (2, *S)`` in the updraft ``w`` (see the module docstring for the attitude)."""
        ya = np.asarray(y, dtype=np.float64)
        uu = np.asarray(u, dtype=np.float64)
        wa = np.asarray(w, dtype=np.float64)
        dy = self.derivative(ya, uu, wa)
        bank, v = ya[BANK], ya[SPEED]
        if self.any_glide:
            s = self._sink(v, bank)
            ratio = np.clip(s / v, -1.0, 1.0)
            # d(s/V)/dt from ds/dV = (2 A V + B)/√cos φ and ds/dφ = s·tan(φ)/2
            ds_dv = (2.0 * self.A * v + self.B) / np.sqrt(np.cos(bank))
            dratio = ((ds_dv * v - s) / (v * v)) * dy[SPEED] + (s * np.tan(bank) / 2.0 / v) * dy[
                BANK]
            gamma_rate = dratio / np.sqrt(np.maximum(1.0 - ratio * ratio, 1e-300))
            air_vz = np.where(self.glide, s, 0.0)
            pitch_rate = np.where(self.glide, -gamma_rate, 0.0)
        else:
            air_vz = np.zeros(np.shape(v))
            pitch_rate = np.zeros(np.shape(v))
        att = attitude(ya[HEADING], bank, v, air_vz)
        rates = body_rates_from_euler_rates(att.roll, att.pitch, -dy[BANK], pitch_rate,
                                            dy[HEADING])
        return FlightOutputs(
            vz=np.asarray(dy[Z]), omega=np.asarray(dy[HEADING]), roll=att.roll,
            pitch=att.pitch, yaw=att.yaw, quat=att.quat, rates=rates,
        )


@dataclass(frozen=True, slots=True)
class PathState:
    """A vehicle on a kinematic path at one instant: ``position`` (3,) m, ``velocity`` (3,)
    m/s, ``heading``, ``bank`` rad, ``airspeed`` m/s and the implied :class:`FlightOutputs`
    (0-d arrays; ``quat`` (4,), ``rates`` (3,))."""

    position: F8
    velocity: F8
    heading: float
    bank: float
    airspeed: float
    outputs: FlightOutputs


@dataclass(frozen=True, slots=True)
class PathStates:
    """V vehicles on their kinematic paths at one instant: ``position``, ``velocity`` (V, 3)
    m, m/s, ``heading``, ``bank``, ``airspeed`` (V,) and the implied :class:`FlightOutputs`
    (arrays (V,), ``quat`` (V, 4), ``rates`` (V, 3))."""

    position: F8
    velocity: F8
    heading: F8
    bank: F8
    airspeed: F8
    outputs: FlightOutputs


def path_states(trajs: Sequence[Trajectory], t: float, dt: float = 1e-3) -> PathStates:
    """The states of vehicles flying ``trajs`` at time ``t`` s. A vehicle's attitude is its
    trajectory's own when it carries one (a logged attitude, :meth:`Trajectory.attitude`),
    otherwise the one its path implies: yaw = its heading, roll = −bank (the trajectory's
    bank; for a timed geometric path the coordinated-turn bank), pitch = −asin(vz / speed)
    (the climb of the path; 0 when level): :func:`attitude` with the path's climb. Velocity,
    turn rate and body rates are central differences over ``dt`` s."""
    times = np.array([t - dt / 2, t, t + dt / 2])
    s = sample_paths(trajs, np.broadcast_to(times, (len(trajs), 3)))
    xyz = np.stack([s["x"], s["y"], s["z"]], axis=-1)  # (V, 3 times, 3)
    speed, vz = s["airspeed"], s["vz"]
    implied = attitude(s["heading"], s["bank"], speed, vz)
    roll, pitch, yaw, quat = implied.roll, implied.pitch, implied.yaw, implied.quat
    for v, traj in enumerate(trajs):
        logged = traj.attitude(times)
        if logged is not None:
            quat[v] = logged
            roll[v], pitch[v], yaw[v] = euler_from_quat(logged)
    rates = body_rates_from_quats(quat[:, 0], quat[:, 2], dt)
    omega = _wrap(s["heading"][:, 2] - s["heading"][:, 0]) / dt
    out = FlightOutputs(
        vz=vz[:, 1], omega=omega, roll=roll[:, 1], pitch=pitch[:, 1], yaw=yaw[:, 1],
        quat=quat[:, 1], rates=rates,
    )
    return PathStates(
        position=xyz[:, 1], velocity=(xyz[:, 2] - xyz[:, 0]) / dt, heading=s["heading"][:, 1],
        bank=s["bank"][:, 1], airspeed=speed[:, 1], outputs=out,
    )


def path_state(traj: Trajectory, t: float, dt: float = 1e-3) -> PathState:
    """The state of one vehicle flying ``traj`` at time ``t`` s (:func:`path_states`)."""
    ps = path_states((traj,), t, dt)
    o = ps.outputs
    return PathState(
        position=ps.position[0], velocity=ps.velocity[0], heading=float(ps.heading[0]),
        bank=float(ps.bank[0]), airspeed=float(ps.airspeed[0]),
        outputs=FlightOutputs(vz=o.vz[0], omega=o.omega[0], roll=o.roll[0], pitch=o.pitch[0],
                              yaw=o.yaw[0], quat=o.quat[0], rates=o.rates[0]),
    )


def warm_up() -> None:
    """Compile, or load from the on-disk cache, the continuous flight model's kernels and the
    soaring kernels (:func:`sim_core.soaring.warm_up`), so that no later step pays it: call it
    before a realtime loop, or after installing."""
    soaring_warm_up()
    law = Law()
    model = FlightModel.from_params([FlightParams()], glide=[True],
                                    polar=(law.Sink_A, law.Sink_B, law.Sink_C), g=law.g)
    y0, u0 = np.array([[0.0], [0.0], [100.0], [0.0], [0.0], [10.0]]), np.array([[0.1], [10.0]])
    model.step(y0, u0, 0.02, updraft=lambda xy: np.zeros(xy.shape[1:]))
    model.outputs(y0, u0)
