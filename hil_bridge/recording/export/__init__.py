"""Real tools out: echoes and recordings in the formats analysis tools open natively.

- :mod:`hil_bridge.recording.export.echo_file`: one echo as ``.npz``, MATLAB v5 ``.mat`` or
``.wav``;
- :mod:`hil_bridge.recording.export.matlab`: a recording's echoes, pings and glider tracks as
``.mat``;
- :mod:`hil_bridge.recording.export.ros2`: a recording as a ROS 2 (Jazzy) bag (MCAP, CDR,
``ros2msg`` schemas, through rosbags' type store);
- :mod:`hil_bridge.recording.export.foxglove`: a recording with Foxglove's well-known schemas.

Every output goes through :func:`hil_bridge.outputs.atomic_output` (never clobbered without
``overwrite``, never half-written).
"""

from __future__ import annotations

import importlib
import os
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hil_bridge.recording.export.common import ExportCounts

__all__ = ["EXPORTERS", "run_exporter"]

#: ``bag export`` format -> ``"module:function(src, dst, *, overwrite) -> ExportCounts"``
EXPORTERS: dict[str, str] = {
    "ros2": "hil_bridge.recording.export.ros2:export_ros2",
    "foxglove": "hil_bridge.recording.export.foxglove:export_foxglove",
    "mat": "hil_bridge.recording.export.matlab:export_mat",
}


def run_exporter(kind: str, src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
                 overwrite: bool = False) -> ExportCounts:
    """Export the recording ``src`` to ``dst`` as ``kind`` (a key of :data:`EXPORTERS`)."""
    try:
        module, func = EXPORTERS[kind].split(":")
    except KeyError:
        raise ValueError(f"unknown export format {kind!r}; expected one of "
                         f"{sorted(EXPORTERS)}") from None
    result: ExportCounts = getattr(importlib.import_module(module), func)(
        src, dst, overwrite=overwrite)
    return result
