"""The frames the bridge sends, as signal values from bus messages (``drivers/can/glider.dbc``).

Each function returns ``(frame name, signal values)`` pairs for
:meth:`~drivers.can.codec.GliderCanCodec.encode`, in the order they go on the wire:

* a state sample (:func:`pos_frame`, :func:`attitude_frames`, :func:`motion_frame`):
  GLIDER_STATE_POS (``lockstep = 1`` for a lockstep sample), GLIDER_STATE_QUAT and
  GLIDER_STATE_RATES for a state that carries an attitude (the quaternion with ``qw >= 0``: -q
  is the same rotation), then GLIDER_STATE_MOTION, which completes the sample; all but POS carry
  the sample's ``state_counter`` (:mod:`drivers.can.samples` assembles them again);
* a neighbour list (:func:`neighbour_frames`): NEIGHBOR_POS + NEIGHBOR_MOTION per neighbour
  (positions relative to the glider's own state, at most :data:`MAX_NEIGHBOURS`), or one
  NEIGHBOR_MOTION with ``nb_count = 0`` for an empty list;
* BRIDGE_HEARTBEAT (:func:`heartbeat_frame`), its ``bridge_mode`` from :func:`bridge_mode`.
"""

from __future__ import annotations

import math

from hil_bridge.bus.messages import GliderNeighbors, GliderState

__all__ = [
    "BRIDGE_MODES",
    "MAX_NEIGHBOURS",
    "Frame",
    "attitude_frames",
    "bridge_mode",
    "has_attitude",
    "heartbeat_frame",
    "motion_frame",
    "neighbour_frames",
    "pos_frame",
]

#: A frame to send: its name in the DBC and its signal values.
Frame = tuple[str, dict[str, float]]

#: bridge_mode values (BRIDGE_HEARTBEAT.bridge_mode).
BRIDGE_MODES = {"INIT": 0, "RUN": 1, "DEGRADED": 2, "BUS_OFF": 3}
#: Neighbours per list the profile carries (nb_count is 4 bits).
MAX_NEIGHBOURS = 15


def has_attitude(st: GliderState) -> bool:
    """Whether the state carries an attitude (publishers older than it leave NaN)."""
    return all(math.isfinite(v) for v in (st.qw, st.qx, st.qy, st.qz, st.roll_rate,
                                          st.pitch_rate, st.yaw_rate))


def pos_frame(st: GliderState, *, lockstep: bool = False) -> Frame:
    """GLIDER_STATE_POS of ``st``; ``lockstep = 1`` marks a lockstep sample."""
    values: dict[str, float] = {"x_m": st.x, "y_m": st.y, "z_m": st.z}
    if lockstep:
        values["lockstep"] = 1
    return "GLIDER_STATE_POS", values


def attitude_frames(st: GliderState, counter: int) -> list[Frame]:
    """GLIDER_STATE_QUAT and GLIDER_STATE_RATES of ``st``, none when it carries no attitude."""
    if not has_attitude(st):
        return []
    sign = -1.0 if st.qw < 0 else 1.0
    return [
        ("GLIDER_STATE_QUAT",
         {"qw": sign * st.qw, "qx": sign * st.qx, "qy": sign * st.qy, "qz": sign * st.qz,
          "state_counter": counter}),
        ("GLIDER_STATE_RATES",
         {"roll_rate_rps": st.roll_rate, "pitch_rate_rps": st.pitch_rate,
          "yaw_rate_rps": st.yaw_rate, "state_counter": counter}),
    ]


def motion_frame(st: GliderState, counter: int) -> Frame:
    """GLIDER_STATE_MOTION of ``st``, the frame that completes its sample."""
    return (
        "GLIDER_STATE_MOTION",
        {"heading_rad": st.heading, "bank_rad": st.bank, "airspeed_mps": st.airspeed,
         "vz_mps": st.vz, "alive": float(st.alive), "state_counter": counter},
    )


def neighbour_frames(own: GliderState, nbs: GliderNeighbors, nb_set: int) -> list[Frame]:
    """The list ``nbs`` (its first :data:`MAX_NEIGHBOURS`) relative to ``own``, as set
    ``nb_set``."""
    k = min(len(nbs.ids), MAX_NEIGHBOURS)
    if k == 0:
        return [("NEIGHBOR_MOTION",
                 {"nb_slot": 0, "nb_count": 0, "nb_heading_rad": 0.0, "nb_airspeed_mps": 0.0,
                  "nb_vz_mps": 0.0, "nb_set": nb_set})]
    frames: list[Frame] = []
    for i in range(k):
        frames.append(
            ("NEIGHBOR_POS",
             {"nb_slot": i, "nb_dx_m": float(nbs.x[i]) - own.x,
              "nb_dy_m": float(nbs.y[i]) - own.y, "nb_dz_m": float(nbs.z[i]) - own.z}))
        frames.append(
            ("NEIGHBOR_MOTION",
             {"nb_slot": i, "nb_count": k, "nb_heading_rad": float(nbs.heading[i]),
              "nb_airspeed_mps": float(nbs.airspeed[i]), "nb_vz_mps": float(nbs.vz[i]),
              "nb_set": nb_set}))
    return frames


def bridge_mode(has_state: bool, link_state: str) -> int:
    """INIT before the glider's first state, else RUN on a link that is up, BUS_OFF, or
    DEGRADED (any other link state)."""
    if not has_state:
        return BRIDGE_MODES["INIT"]
    if link_state == "bus_off":
        return BRIDGE_MODES["BUS_OFF"]
    if link_state == "up":
        return BRIDGE_MODES["RUN"]
    return BRIDGE_MODES["DEGRADED"]


def heartbeat_frame(counter: int, mode: int, cmd_state: int, sim_time_ms: int) -> Frame:
    """BRIDGE_HEARTBEAT: its counter, the bridge mode, the glider's command supervision state
    and the sim time of its latest state (ms, modulo 2^32)."""
    return (
        "BRIDGE_HEARTBEAT",
        {"bridge_counter": counter, "bridge_mode": mode, "cmd_state": cmd_state,
         "sim_time_ms": sim_time_ms},
    )
