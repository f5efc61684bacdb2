"""A sonar riding on a vehicle: the beam and the ears of one ping, from the sonar's world pose.

A ping's ``az``/``el`` are angles in the sonar frame (x forward, y left, z up; az from +x
towards +y, el towards +z). The sonar's world pose (position m, world-from-sonar quaternion
``[w, x, y, z]``) is its vehicle's pose composed with its mount
(:func:`sim_core.pose.pose_compose`), so the beam rolls and pitches with the vehicle.

The echo model's :class:`~sim_core.sonar.Ear` places an ear in the *beam* frame of one ping
(x along the boresight, y horizontal to the left, z up: :meth:`Beam.frame`). Ears fixed on the
sonar move in that frame from ping to ping and with every roll of the vehicle;
:func:`ears_for_ping` converts sonar-frame ears into the model's form for one ping.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from sim_core.pose import direction_from_az_el, quat_rotate
from sim_core.sonar.params import Beam, Ear

__all__ = ["ears_for_ping", "ping_beam"]


def ping_beam(
    position: ArrayLike, orientation: ArrayLike, az: float, el: float, beamwidth: float
) -> Beam:
    """The beam of a ping at ``az``, ``el`` (rad, sonar frame) from a sonar at ``position``
    (3,) m with world-from-sonar ``orientation`` (4,): boresight = R · (cos el cos az,
    cos el sin az, sin el)."""
    if not (math.isfinite(az) and math.isfinite(el)):
        raise ValueError(f"ping az/el must be finite, got {az!r}, {el!r}")
    return Beam(position, quat_rotate(orientation, direction_from_az_el(az, el)), beamwidth)


def ears_for_ping(
    beam: Beam,
    orientation: ArrayLike,
    positions: ArrayLike,
    axes: ArrayLike,
    beamwidths: Sequence[float | None],
) -> tuple[Ear, ...]:
    """Ears at ``positions`` (K, 3) m with beam ``axes`` (K, 3) (sonar frame, any length) of a
    sonar at world-from-sonar ``orientation``, as the model's :class:`Ear` in the frame of
    ``beam`` (offset, yaw/pitch of the axis); ``beamwidths`` (K,) rad, None = the ping's."""
    frame = beam.frame()  # rows: forward, left, up of the beam, world axes
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    ax = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    offsets = quat_rotate(orientation, pos) @ frame.T
    local = quat_rotate(orientation, ax / np.linalg.norm(ax, axis=1, keepdims=True)) @ frame.T
    return tuple(
        Ear(offset=(float(o[0]), float(o[1]), float(o[2])),
            yaw_rad=math.atan2(float(a[1]), float(a[0])),
            pitch_rad=math.asin(float(np.clip(a[2], -1.0, 1.0))), beamwidth_rad=bw)
        for o, a, bw in zip(offsets, local, beamwidths, strict=True)
    )
