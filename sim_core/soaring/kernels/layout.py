"""The soaring kernels' array layouts (B runs, N glider slots, T thermal slots, K list slots).

* glider state ``S`` (STATE_ROWS, B, N), rows ``ROW_*``; ``alive`` (B, N);
* thermals ``th`` (TH_ROWS, B, T), rows ``TH_*``; ``th_on`` (2, B, T): valid, fades;
* per-run parameters ``par`` (B, len(PAR)), columns named by :data:`PAR` (``P_*``);
* neighbour lists ``nb`` (B, N, K) glider indices, nearest first, ``cnt`` (B, N) used slots;
* metric accumulators ``accf`` (3, B) (``ACC_*``) and ``acci`` (4, B) (``CNT_*``);

and the bounds the kernels clip to. numba compiles these values into the kernels that read them
(:mod:`sim_core.soaring.kernels.cache` says how a change here reaches them).
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

#: Cap of a neighbour's distance weight (d/R)^p, reached only as d → 0 with p < 0.
W_MAX = 1e100
#: Acceleration components beyond ±A_MAX (m/s², or infinite, or NaN → 0) are clipped to it, so
#: ‖a‖² cannot overflow (never hit in the seed's runs, whose |a| stays below 1e6).
A_MAX = 1e100

#: In ``thermalFadeMode: seconds`` a plateau ends when its timer (a sum of dt) reaches the
#: plateau length less this many seconds, so rounding in the sum cannot add a step.
FADE_TOLERANCE = 1e-9
