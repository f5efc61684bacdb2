"""Compiled kernels of seed 002's soaring model: the one implementation of its physics.

Everything that flies is here, compiled by numba with an on-disk cache (:mod:`.cache`: compiled
once per installation and CPU, and recompiled whole when any module of this package changes).
The public functions of :mod:`~sim_core.soaring.glider`, :mod:`~sim_core.soaring.thermals`,
:mod:`~sim_core.soaring.boids` and :class:`~sim_core.soaring.swarm.SwarmSim` are thin wrappers
that shape arrays and call these.

Modules: :mod:`.octave` (Octave's arithmetic: norms, powers, fma, NaN rules), :mod:`.glider`
(polar sink, command from an acceleration, one glider step), :mod:`.thermals` (updraft, fade
cycle), :mod:`.boids` (the controller and the neighbour search), :mod:`.step` (the swarm step
and the loop over steps); this module holds the layouts they share.

Per glider, a step is a scalar loop over float64 with the seed's operations in the seed's order
(``docs/spec/seed_models.md`` §3), each evaluated as GNU Octave evaluates the seed's MATLAB
(:mod:`.octave`); ``./`` divides; exp, cos, sin, tan, atan and acos are libm's. No fast-math,
no reordered sums; sums over neighbours and gliders run in index order. So a run's result does
not depend on the batch it is stepped in, one machine gives the same bits every time, and the
seed's own Octave run (``tests/data/seed002_matlab``) is reproduced to the last bit where this
machine's libm is the one it used.

Layouts (B runs, N glider slots, T thermal slots, K list slots):

* glider state ``S`` (STATE_ROWS, B, N), rows ``ROW_*``; ``alive`` (B, N);
* thermals ``th`` (TH_ROWS, B, T), rows ``TH_*``; ``th_on`` (2, B, T): valid, fades;
* per-run parameters ``par`` (B, len(PAR)), columns named by :data:`PAR` (``P_*``);
* neighbour lists ``nb`` (B, N, K) glider indices, nearest first, ``cnt`` (B, N) used slots;
* metric accumulators ``accf`` (3, B) (``ACC_*``) and ``acci`` (4, B) (``CNT_*``).
"""

from __future__ import annotations

#: Rows of the glider state block. VX, VY (v cos ψ, v sin ψ) are derived at the start of a
#: step; VX..VZ are the rows a neighbour is read from.
ROW_VX, ROW_VY, ROW_X, ROW_Y, ROW_Z, ROW_VZ, ROW_HEADING, ROW_OMEGA, ROW_SPEED, ROW_BANK = range(10)
STATE_ROWS = 10

#: Rows of the thermal block: centre m, radius m, strength m/s, plateau top m/s, direction ±1,
#: plateau timer (steps or s).
TH_X, TH_Y, TH_R, TH_W, TH_WMAX, TH_DIR, TH_TIMER = range(7)
TH_ROWS = 7
ON_VALID, ON_FADE = 0, 1

ACC_FLIGHT, ACC_HEIGHT, ACC_THERMAL = range(3)
CNT_AGENTS, CNT_LIVING, CNT_COLL, CNT_GROUND = range(4)

#: Columns of the per-run parameter table: the law's names, then derived values.
PAR: tuple[str, ...] = (
    "g", "cohesion", "heightFactorPower", "cohesionAscensionIgnore", "cohesionAscensionMax",
    "ascensionFactorPower", "cohPower", "separation", "separationHeightWidth", "sepPower",
    "alignment", "alignmentHeightWidth", "aliPower", "migration", "migPower", "waggle",
    "thermalBankFactor", "neighborRadius", "forwardSpeedMin", "forwardSpeedMax", "bankMin",
    "bankMax", "Sink_A", "Sink_B", "Sink_C", "collisionKillDistance", "agentCeiling",
    "agentFloor", "k", "unified", "target_x", "target_y", "bank_rate_max", "speed_rate_max",
    "fov_limited", "half_fov", "fade_rate", "fade_incr", "fade_top", "fade_bottom",
    "map_min", "map_cell",
)
(P_G, P_KC, P_HFP, P_ASC_IGN, P_ASC_MAX, P_AFP, P_COH_P, P_KS, P_SEP_W, P_SEP_P, P_KA, P_ALI_W,
 P_ALI_P, P_KM, P_MIG_P, P_KW, P_TBF, P_RADIUS, P_V_MIN, P_V_MAX, P_B_MIN, P_B_MAX, P_SINK_A,
 P_SINK_B, P_SINK_C, P_KILL, P_CEIL, P_FLOOR, P_K, P_UNIFIED, P_TX, P_TY, P_BANK_RATE,
 P_SPEED_RATE, P_FOV_LIMITED, P_HALF_FOV, P_FADE_RATE, P_FADE_INCR, P_FADE_TOP, P_FADE_BOTTOM,
 P_MAP_MIN, P_MAP_CELL) = range(len(PAR))
