"""Recording: MCAP bags, the recorder node, scan and recovery, flight-log readers and exports.

``bag`` (the bag format, reading, info), ``bag_writer`` (writing, JSON export, recovery),
``bag_player`` (replay onto the bus), ``recorder`` (the launch's recording node),
``mcap_scan`` (record-by-record reading that survives damage), ``replay_transport`` (the
``replay://`` bus backend), ``logs`` (PX4 ULog, ArduPilot DataFlash and tlog, ROS 2 bags, CSV
and NPZ tables, echoloop recordings → one pose log) and ``export`` (ROS 2, Foxglove, MATLAB,
echo files).

May import: ``hil_bridge.bus``, ``hil_bridge.files``, ``hil_bridge.errors``,
``hil_bridge.outputs`` and ``sim_core``.
"""
