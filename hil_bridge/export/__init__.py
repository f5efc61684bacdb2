"""Real tools out: echoes and recordings in the formats analysis tools open natively.

- :mod:`hil_bridge.export.echo_file`: one echo as ``.npz``, MATLAB v5 ``.mat`` or ``.wav``;
- :mod:`hil_bridge.export.matlab`: a recording's echoes, pings and glider tracks as ``.mat``;
- :mod:`hil_bridge.export.ros2`: a recording as a ROS 2 bag (MCAP, CDR, ``ros2msg`` schemas);
- :mod:`hil_bridge.export.foxglove`: a recording with Foxglove's well-known schemas.

Every output goes through :func:`hil_bridge.outputs.atomic_output` (never clobbered without
``overwrite``, never half-written).
"""
