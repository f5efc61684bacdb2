"""What every exporter needs: decoded messages of a recording, glider and sonar poses.

Poses follow REP 103 (world ENU, body FLU, quaternions ``[w, x, y, z]`` world-from-body).
A ``GliderState``'s attitude is :func:`hil_bridge.bus.messages.state_quaternions`: its own
quaternion (as the server publishes it) or, for older states (NaN there), the one
:func:`sim_core.flight.glide_attitude` derives from its heading, bank and airspeed, as the live
view shows it. A ``SonarEcho`` that carries the sonar's pose at emission (finite
``position``, ``orientation``, ``boresight``) is used as is, turned so that x is the
boresight; older echoes are located as the server used to compute them: at the mount
vehicle's latest state, boresight at world azimuth ``heading + az`` and elevation ``el``.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_bridge.bus.codec import decode_payload
from hil_bridge.errors import CodecError
from hil_bridge.recording.bag import BagMessage, read_bag
from sim_core.pose import quat_from_euler

__all__ = ["STATE_TOPIC", "Decoded", "ExportCounts", "SonarPose", "batches", "decoded",
           "glider_velocities", "mount_id", "sonar_pose", "velocities_enu"]

STATE_TOPIC = re.compile(r"^/glider/(\d+)/state$")
FloatArray = NDArray[np.float64]


@dataclass
class ExportCounts:
    """What an export wrote and skipped (per reason), returned by every exporter."""

    messages: int = 0
    written: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    truncated: bool = False

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1

    def as_dict(self) -> dict[str, Any]:
        return {"messages": self.messages, "written": self.written,
                "skipped": dict(sorted(self.skipped.items())), "truncated": self.truncated}


@dataclass(frozen=True, slots=True)
class Decoded:
    """A recorded message and its decoded payload."""

    raw: BagMessage
    msg: Any

    @property
    def topic(self) -> str:
        return self.raw.topic


def decoded(src: str | os.PathLike[str], counts: ExportCounts,
            topics: Iterable[str] | None = None) -> Iterator[Decoded]:
    """Every decodable message of ``src`` in file order; undecodable ones are counted in
    ``counts.skipped["undecodable"]`` and left out."""
    from hil_bridge.recording.bag import BagInfo

    info = BagInfo(str(src))
    for m in read_bag(Path(src), topics, info=info):
        counts.messages += 1
        try:
            msg = decode_payload(m.header.type, m.header.v, m.payload)
        except CodecError:
            counts.skip("undecodable")
            continue
        yield Decoded(m, msg)
    counts.truncated = info.truncated


def mount_id(frame_id: str) -> int | None:
    """The vehicle id of an echo's ``frame_id`` (``glider/<id>``), or None."""
    head, _, tail = frame_id.partition("/")
    return int(tail) if head == "glider" and tail.isdigit() else None


def glider_velocities(states: list[Any]) -> FloatArray:
    """World ENU velocities (K, 3) m/s of K ``GliderState`` (:func:`velocities_enu`)."""
    a = np.array([[st.heading, st.airspeed, st.vz] for st in states],
                 dtype=np.float64).reshape(-1, 3)
    return velocities_enu(a[:, 0], a[:, 1], a[:, 2])


def velocities_enu(heading: FloatArray, airspeed: FloatArray, vz: FloatArray) -> FloatArray:
    """World ENU velocities (K, 3) m/s: ``airspeed`` (K,) m/s along ``heading`` (K,) rad
    (from +x towards +y), plus ``vz`` (K,) m/s."""
    v = np.empty((heading.shape[0], 3))
    np.multiply(airspeed, np.cos(heading), out=v[:, 0])
    np.multiply(airspeed, np.sin(heading), out=v[:, 1])
    v[:, 2] = vz
    return v


def batches(items: Iterator[Decoded], size: int = 4096) -> Iterator[list[Decoded]]:
    """``items`` in lists of at most ``size`` (exporters vectorise the pose algebra per list)."""
    batch: list[Decoded] = []
    for item in items:
        batch.append(item)
        if len(batch) == size:
            yield batch
            batch = []
    if batch:
        yield batch


@dataclass(frozen=True, slots=True)
class SonarPose:
    """Where an echo was heard from: ``position`` (3,) m, ``orientation`` (4,) world-from-sonar
    (sonar x = boresight), ``boresight`` (3,) unit vector, all world ENU."""

    position: FloatArray
    orientation: FloatArray
    boresight: FloatArray


def sonar_pose(echo: Any, ping: Any | None, mount_state: Any | None) -> SonarPose | None:
    """The sonar pose of ``echo`` (module docstring); None when nothing locates it."""
    pos = np.asarray(echo.position, dtype=np.float64)
    ori = np.asarray(echo.orientation, dtype=np.float64)
    bore = np.asarray(echo.boresight, dtype=np.float64)
    if np.all(np.isfinite(pos)) and np.all(np.isfinite(ori)) and np.all(np.isfinite(bore)):
        from sim_core.pose import quat_between, quat_multiply, quat_rotate

        # world-from-sonar turned by the shortest arc that takes the sonar's x (its mount's
        # forward axis) to the ping's boresight: a frame whose x is the beam axis
        turn = quat_between(quat_rotate(ori, [1.0, 0.0, 0.0]), bore)
        return SonarPose(pos, quat_multiply(turn, ori), bore)
    if mount_state is None:
        return None
    az = float(ping.az) if ping is not None else 0.0
    el = float(ping.el) if ping is not None else 0.0
    yaw = float(mount_state.heading) + az
    b = np.array([math.cos(el) * math.cos(yaw), math.cos(el) * math.sin(yaw), math.sin(el)])
    return SonarPose(np.array([mount_state.x, mount_state.y, mount_state.z], dtype=np.float64),
                     quat_from_euler(0.0, -el, yaw), b)

