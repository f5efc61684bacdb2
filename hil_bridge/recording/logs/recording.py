"""echoloop's own recordings (``echoloop bag record``, ``launch --record``): one glider's states.

Poses from ``/glider/<id>/state`` (``GliderState``: x, y, z m ENU, heading, bank, airspeed);
``vehicle_id`` (or ``topic``, the state topic) chooses the glider when the recording has
several. Time: the states'
``stamp_ns`` (sim time). States with ``alive`` false are dropped; a state repeated with a new
stamp (recordings of servers older than the continuous flight model held states between
physics steps) is kept, so the replay holds too. When the states carry an attitude quaternion
(``qw, qx, qy, qz``, finite) it is used.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from hil_bridge.recording.logs.track import NoPoseError, PoseLog, describe

__all__ = ["read_recording"]

_STATE = re.compile(r"^/glider/(\d+)/state$")


def read_recording(
    path: Path, *, vehicle_id: int | None = None, topic: str | None = None
) -> PoseLog:
    """The states of one glider of an echoloop recording (module docstring)."""
    from hil_bridge.bus.codec import decode_payload
    from hil_bridge.errors import CodecError
    from hil_bridge.recording.bag import read_bag

    found: dict[str, int] = {}
    ids: set[int] = set()
    for m in read_bag(path):
        found[m.topic] = found.get(m.topic, 0) + 1
        hit = _STATE.match(m.topic)
        if hit:
            ids.add(int(hit.group(1)))
    if not ids:
        raise NoPoseError(f"{path}: echoloop recording without /glider/<id>/state messages; it "
                          f"holds {describe(found)}")
    if topic is not None:
        named = _STATE.match(topic.strip())
        if named is None or int(named.group(1)) not in ids or (
                vehicle_id is not None and int(named.group(1)) != vehicle_id):
            states = {t: n for t, n in found.items() if _STATE.match(t)}
            raise ValueError(f"{path}: topic {topic!r}: not a state topic of this recording"
                             f"{'' if vehicle_id is None else f' for id {vehicle_id}'}; it has "
                             f"{describe(states)}")
        vehicle_id = int(named.group(1))
    if vehicle_id is None:
        if len(ids) > 1:
            raise ValueError(f"{path}: holds vehicles {sorted(ids)}; choose one with an id")
        vehicle_id = next(iter(ids))
    elif vehicle_id not in ids:
        raise ValueError(f"{path}: no /glider/{vehicle_id}/state; ids present: {sorted(ids)}")
    topic_name = f"/glider/{vehicle_id}/state"
    rows: list[tuple[float, ...]] = []
    bad = 0
    for m in read_bag(path, [topic_name]):
        try:
            s: Any = decode_payload(m.header.type, m.header.v, m.payload)
        except CodecError:
            bad += 1
            continue
        if not getattr(s, "alive", True):
            continue
        q = tuple(float(getattr(s, k, np.nan)) for k in ("qw", "qx", "qy", "qz"))
        rows.append((s.stamp_ns * 1e-9, s.x, s.y, s.z, s.heading, s.bank, s.airspeed, *q))
    if not rows:
        raise NoPoseError(f"{path}: {topic_name} holds no live state")
    a = np.asarray(rows, dtype=np.float64)
    has_q = bool(np.all(np.isfinite(a[:, 7:11])))
    log = PoseLog(format="echoloop recording", source=topic_name, t=a[:, 0], position=a[:, 1:4],
                  frame="enu", heading=a[:, 4], bank=a[:, 5], speed=a[:, 6],
                  att_t=a[:, 0] if has_q else None, att_q=a[:, 7:11] if has_q else None,
                  att_source=f"{topic_name} quaternion" if has_q else "",
                  vehicle_id=vehicle_id)
    if bad:
        log.notes.append(f"{bad} undecodable state(s) skipped")
    return log
