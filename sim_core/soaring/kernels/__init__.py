"""Compiled kernels of seed 002's soaring model: the one implementation of its physics, and of
the continuous flight model's right-hand side and RK4 sub-steps (:mod:`sim_core.flight`, which
uses the seed's polar ``sink``).

Everything that flies is here, compiled by numba and cached on disk (machine code is written
next to these files, or under ``NUMBA_CACHE_DIR``, and reused by later processes, so the compile
cost is paid once per installation and CPU). The public functions of
:mod:`~sim_core.soaring.glider`, :mod:`~sim_core.soaring.thermals`, :mod:`~sim_core.soaring.boids`
and :class:`~sim_core.soaring.swarm.SwarmSim` are thin wrappers that shape arrays and call these.
One idea a module:

* :mod:`.layout`: the arrays' rows and columns (``ROW_*``, ``TH_*``, ``PAR``/``P_*``, ...);
* :mod:`.arith`: Octave's scalar arithmetic, and ``jit``, the compiler they all go through;
* :mod:`.kinematics`: one glider's step, the sink polar and the command;
* :mod:`.updrafts`: the thermals' updraft and fade cycle;
* :mod:`.flocking`: the Boids controller and the neighbour lists;
* :mod:`.stepping`: the swarm step and :func:`advance`;
* :mod:`.batched`: the elementwise entry points of the public wrappers;
* :mod:`.continuous`: the continuous flight model's right-hand side and RK4 stages.

They call each other across files, and numba checks a cached function only against its own
file: :mod:`.cache` makes them one unit, so any change to any of them compiles all of them again
(:data:`UNIT`).

Per glider, a step is a scalar loop over float64 with the seed's operations in the seed's order
(``docs/spec/seed_models.md`` §3), each evaluated as GNU Octave evaluates the seed's MATLAB
(:mod:`.arith`); exp, cos, sin, tan, atan and acos are libm's. No fast-math, no reordered sums;
sums over neighbours and gliders run in index order. So a run's result does not depend on the
batch it is stepped in, one machine gives the same bits every time, and the seed's own Octave
run (``tests/data/seed002_matlab``) is reproduced to the last bit where this machine's libm is
the one it used.
"""

from __future__ import annotations

from sim_core.soaring.kernels import (
    arith,
    batched,
    continuous,
    flocking,
    kinematics,
    layout,
    stepping,
    updrafts,
)
from sim_core.soaring.kernels.arith import (
    epow,
    fma,
    maximum,
    minimum,
    norm2,
    norm3,
    round_half_away,
    sign,
    spow,
)
from sim_core.soaring.kernels.batched import (
    accel_many,
    command_many,
    controller,
    cos_sin,
    fade_many,
    fly_many,
    lists_many,
    sink_many,
    updraft_many,
)
from sim_core.soaring.kernels.cache import bind
from sim_core.soaring.kernels.continuous import (
    FP_A,
    FP_B,
    FP_BANK_RATE,
    FP_BANK_TAU,
    FP_C,
    FP_CEIL,
    FP_FLOOR,
    FP_G,
    FP_ROWS,
    FP_SPEED_RATE,
    FP_SPEED_TAU,
    flight_finish,
    flight_rhs,
    flight_stage,
)
from sim_core.soaring.kernels.flocking import (
    accel,
    find_lists,
    headings,
)
from sim_core.soaring.kernels.kinematics import (
    command,
    fly,
    sink,
)
from sim_core.soaring.kernels.layout import (
    A_MAX,
    ACC_FLIGHT,
    ACC_HEIGHT,
    ACC_THERMAL,
    CNT_AGENTS,
    CNT_COLL,
    CNT_GROUND,
    CNT_LIVING,
    FADE_TOLERANCE,
    ON_FADE,
    ON_VALID,
    P_AFP,
    P_ALI_P,
    P_ALI_W,
    P_ASC_IGN,
    P_ASC_MAX,
    P_B_MAX,
    P_B_MIN,
    P_BANK_RATE,
    P_CEIL,
    P_COH_P,
    P_FADE_BOTTOM,
    P_FADE_INCR,
    P_FADE_RATE,
    P_FADE_TOP,
    P_FLOOR,
    P_FOV_LIMITED,
    P_G,
    P_HALF_FOV,
    P_HFP,
    P_K,
    P_KA,
    P_KC,
    P_KILL,
    P_KM,
    P_KS,
    P_KW,
    P_MAP_CELL,
    P_MAP_MIN,
    P_MIG_P,
    P_RADIUS,
    P_SEP_P,
    P_SEP_W,
    P_SINK_A,
    P_SINK_B,
    P_SINK_C,
    P_SPEED_RATE,
    P_TBF,
    P_TX,
    P_TY,
    P_UNIFIED,
    P_V_MAX,
    P_V_MIN,
    PAR,
    ROW_BANK,
    ROW_HEADING,
    ROW_OMEGA,
    ROW_SPEED,
    ROW_VX,
    ROW_VY,
    ROW_VZ,
    ROW_X,
    ROW_Y,
    ROW_Z,
    STATE_ROWS,
    TH_DIR,
    TH_R,
    TH_ROWS,
    TH_TIMER,
    TH_W,
    TH_WMAX,
    TH_X,
    TH_Y,
    W_MAX,
)
from sim_core.soaring.kernels.stepping import (
    advance,
)
from sim_core.soaring.kernels.updrafts import (
    fade,
    updraft,
)

#: the modules of the kernels, cached as one unit (:mod:`.cache`)
UNIT = (arith, batched, continuous, flocking, kinematics, layout, stepping, updrafts)
bind(UNIT)

__all__ = [
    "ACC_FLIGHT",
    "ACC_HEIGHT",
    "ACC_THERMAL",
    "A_MAX",
    "CNT_AGENTS",
    "CNT_COLL",
    "CNT_GROUND",
    "CNT_LIVING",
    "FADE_TOLERANCE",
    "FP_A",
    "FP_B",
    "FP_BANK_RATE",
    "FP_BANK_TAU",
    "FP_C",
    "FP_CEIL",
    "FP_FLOOR",
    "FP_G",
    "FP_ROWS",
    "FP_SPEED_RATE",
    "FP_SPEED_TAU",
    "ON_FADE",
    "ON_VALID",
    "PAR",
    "P_AFP",
    "P_ALI_P",
    "P_ALI_W",
    "P_ASC_IGN",
    "P_ASC_MAX",
    "P_BANK_RATE",
    "P_B_MAX",
    "P_B_MIN",
    "P_CEIL",
    "P_COH_P",
    "P_FADE_BOTTOM",
    "P_FADE_INCR",
    "P_FADE_RATE",
    "P_FADE_TOP",
    "P_FLOOR",
    "P_FOV_LIMITED",
    "P_G",
    "P_HALF_FOV",
    "P_HFP",
    "P_K",
    "P_KA",
    "P_KC",
    "P_KILL",
    "P_KM",
    "P_KS",
    "P_KW",
    "P_MAP_CELL",
    "P_MAP_MIN",
    "P_MIG_P",
    "P_RADIUS",
    "P_SEP_P",
    "P_SEP_W",
    "P_SINK_A",
    "P_SINK_B",
    "P_SINK_C",
    "P_SPEED_RATE",
    "P_TBF",
    "P_TX",
    "P_TY",
    "P_UNIFIED",
    "P_V_MAX",
    "P_V_MIN",
    "ROW_BANK",
    "ROW_HEADING",
    "ROW_OMEGA",
    "ROW_SPEED",
    "ROW_VX",
    "ROW_VY",
    "ROW_VZ",
    "ROW_X",
    "ROW_Y",
    "ROW_Z",
    "STATE_ROWS",
    "TH_DIR",
    "TH_R",
    "TH_ROWS",
    "TH_TIMER",
    "TH_W",
    "TH_WMAX",
    "TH_X",
    "TH_Y",
    "UNIT",
    "W_MAX",
    "accel",
    "accel_many",
    "advance",
    "command",
    "command_many",
    "controller",
    "cos_sin",
    "epow",
    "fade",
    "fade_many",
    "find_lists",
    "flight_finish",
    "flight_rhs",
    "flight_stage",
    "fly",
    "fly_many",
    "fma",
    "headings",
    "lists_many",
    "maximum",
    "minimum",
    "norm2",
    "norm3",
    "round_half_away",
    "sign",
    "sink",
    "sink_many",
    "spow",
    "updraft",
    "updraft_many",
]
