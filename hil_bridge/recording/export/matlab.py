"""A recording as one MATLAB v5 ``.mat`` file (``echoloop bag export IN --mat OUT.mat``).

``load('run.mat')`` gives, in MATLAB's layout (one row per sample, one column per quantity):

- ``echoes``: struct of E echoes — ``samples`` (E×1 cell, each N×C single, re A0, t = 0 at
  emission), ``fs`` (Hz), ``stamp_ns`` (int64 sim time), ``t`` (s), ``sonar_id``,
  ``ping_seq``, ``leaves_in_beam``, ``dropped``, ``error_bound``, ``fidelity`` (cell),
  the ping's ``az``, ``el``, ``beamwidth`` (rad) and ``ping_stamp_ns`` (NaN / -1 when the ping
  is not in the recording), and the sonar pose ``position`` (E×3 m), ``orientation`` (E×4
  ``[w x y z]`` world-from-sonar), ``boresight`` (E×3) (NaN when unknown; see
  :mod:`hil_bridge.recording.export.common` for how it is found);
- ``gliders``: struct with a field ``glider_<id>`` per glider: columns ``t`` (s), ``stamp_ns``,
  ``x, y, z`` (m ENU), ``heading, bank`` (rad), ``airspeed, vz`` (m/s), ``alive``, ``quat`` (K×4,
  :func:`hil_bridge.bus.messages.state_quaternions`);
- ``commands``: struct ``glider_<id>`` with ``t``, ``bank_cmd`` (rad), ``airspeed_cmd`` (m/s);
- ``thermals``: the last ``/thermals``: ``x, y, radius`` (m), ``w_max`` (m/s);
- ``info``: the source file, frames and units.
"""

from __future__ import annotations

import math
import os
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from hil_bridge.bus.messages import (
    GliderCmd,
    GliderState,
    SonarEcho,
    SonarPing,
    ThermalMarkers,
    state_quaternions,
)
from hil_bridge.outputs import atomic_output
from hil_bridge.recording.export.common import (
    STATE_TOPIC,
    ExportCounts,
    batches,
    decoded,
    mount_id,
    sonar_pose,
)

__all__ = ["export_mat"]

_STATE_FIELDS = ("x", "y", "z", "heading", "bank", "airspeed", "vz")


def _cell(items: list[Any]) -> np.ndarray:
    out = np.empty((len(items), 1), dtype=object)
    for i, item in enumerate(items):
        out[i, 0] = item
    return out


def export_mat(src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
               overwrite: bool = False) -> ExportCounts:
    """Write ``dst`` from the recording ``src`` (module docstring)."""
    from scipy.io import savemat

    counts = ExportCounts()
    states: dict[int, list[list[float]]] = defaultdict(list)
    quats: dict[int, list[Any]] = defaultdict(list)
    last_state: dict[int, Any] = {}
    cmds: dict[int, list[tuple[float, float, float]]] = defaultdict(list)
    pings: dict[tuple[int, int], Any] = {}
    echo_rows: list[dict[str, Any]] = []
    thermals: Any = None
    for batch in batches(decoded(src, counts)):
        batch_quats = iter(state_quaternions([d.msg for d in batch
                                              if isinstance(d.msg, GliderState)]))
        for d in batch:
            msg = d.msg
            if isinstance(msg, GliderState):
                hit = STATE_TOPIC.match(d.topic)
                gid = int(hit.group(1)) if hit else msg.glider_id
                states[gid].append([msg.stamp_ns, *(getattr(msg, f) for f in _STATE_FIELDS),
                                    float(msg.alive)])
                quats[gid].append(next(batch_quats))
                last_state[gid] = msg
            elif isinstance(msg, GliderCmd):
                cmds[msg.glider_id].append((msg.stamp_ns * 1e-9, msg.bank_cmd, msg.airspeed_cmd))
            elif isinstance(msg, SonarPing):
                pings[(msg.sonar_id, msg.ping_seq)] = msg
            elif isinstance(msg, SonarEcho):
                ping = pings.get((msg.sonar_id, msg.ping_seq))
                mount = mount_id(d.raw.header.frame_id)
                pose = sonar_pose(msg, ping, last_state.get(mount) if mount is not None else None)
                echo_rows.append({"msg": msg, "ping": ping, "pose": pose})
            elif isinstance(msg, ThermalMarkers):
                thermals = msg
            else:
                counts.skip(f"no MATLAB field for {d.raw.header.type}")
                continue
            counts.written += 1
    data: dict[str, Any] = {
        "echoes": _echoes(echo_rows),
        "gliders": {f"glider_{g}": _track(rows, quats[g]) for g, rows in sorted(states.items())},
        "commands": {f"glider_{g}": {"t": np.array([r[0] for r in rows]),
                                     "bank_cmd": np.array([r[1] for r in rows]),
                                     "airspeed_cmd": np.array([r[2] for r in rows])}
                     for g, rows in sorted(cmds.items())},
        "info": {"source": str(src), "frames": "world ENU (m), body FLU, quaternions [w x y z] "
                 "world-from-body; angles rad; time t = sim time s (stamp_ns ns)",
                 "echo_units": "amplitude re the emitted amplitude A0 at 1 m; t = 0 at emission"},
    }
    if thermals is not None:
        data["thermals"] = {k: np.asarray(getattr(thermals, k), dtype=np.float64)
                            for k in ("x", "y", "radius", "w_max")}
    with atomic_output(Path(dst), overwrite=overwrite, inputs=[src]) as tmp, \
            open(tmp, "wb") as fh:
        savemat(fh, data, format="5", oned_as="column", long_field_names=True)
    return counts


def _track(rows: list[list[float]], quats: list[Any]) -> dict[str, Any]:
    a = np.asarray(rows, dtype=np.float64)
    out: dict[str, Any] = {"t": a[:, 0] * 1e-9, "stamp_ns": a[:, 0].astype(np.int64)}
    for i, name in enumerate(_STATE_FIELDS):
        out[name] = a[:, i + 1]
    out["alive"] = a[:, -1].astype(bool)
    out["quat"] = np.asarray(quats, dtype=np.float64).reshape(-1, 4)
    return out


def _echoes(rows: list[dict[str, Any]]) -> dict[str, Any]:
    nan3, nan4 = [math.nan] * 3, [math.nan] * 4

    def ping_value(r: dict[str, Any], name: str) -> float:
        return math.nan if r["ping"] is None else float(getattr(r["ping"], name))

    return {
        "samples": _cell([np.atleast_2d(r["msg"].samples).T for r in rows]),
        "fs": np.array([r["msg"].fs for r in rows], dtype=np.float64),
        "stamp_ns": np.array([r["msg"].stamp_ns for r in rows], dtype=np.int64),
        "t": np.array([r["msg"].stamp_ns * 1e-9 for r in rows]),
        "sonar_id": np.array([r["msg"].sonar_id for r in rows], dtype=np.int32),
        "ping_seq": np.array([r["msg"].ping_seq for r in rows], dtype=np.int64),
        "leaves_in_beam": np.array([r["msg"].leaves_in_beam for r in rows], dtype=np.int64),
        "dropped": np.array([r["msg"].dropped for r in rows], dtype=np.int64),
        "error_bound": np.array([r["msg"].error_bound for r in rows], dtype=np.float64),
        "fidelity": _cell([r["msg"].fidelity for r in rows]),
        "az": np.array([ping_value(r, "az") for r in rows]),
        "el": np.array([ping_value(r, "el") for r in rows]),
        "beamwidth": np.array([ping_value(r, "beamwidth") for r in rows]),
        "ping_stamp_ns": np.array([-1 if r["ping"] is None else r["ping"].stamp_ns
                                   for r in rows], dtype=np.int64),
        "position": np.array([nan3 if r["pose"] is None else r["pose"].position
                              for r in rows], dtype=np.float64).reshape(-1, 3),
        "orientation": np.array([nan4 if r["pose"] is None else r["pose"].orientation
                                 for r in rows], dtype=np.float64).reshape(-1, 4),
        "boresight": np.array([nan3 if r["pose"] is None else r["pose"].boresight
                               for r in rows], dtype=np.float64).reshape(-1, 3),
    }
