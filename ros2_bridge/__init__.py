"""ros2_bridge: echoloop live on a ROS 2 graph (``pip install 'echoloop[ros2]'``, Linux x86-64).

An edge of echoloop, beside :mod:`drivers`: it may import :mod:`hil_bridge` and :mod:`sim_core`,
and nothing in echoloop imports it (the launch and the CLI name it as a string), so core
echoloop never imports ROS. Modules:

* :mod:`ros2_bridge.config`: the topic mapping (a YAML list, as ``ros_gz_bridge`` takes) and
  the default one; no ROS import.
* :mod:`ros2_bridge.convert`: bus messages as ROS 2 messages and ROS 2 commands as bus ones.
* :mod:`ros2_bridge.bridge`: the bridge node (launch entry ``ros2_bridge.bridge:Ros2Bridge``).
* :mod:`ros2_bridge.cli`: ``echoloop ros2 bridge|mapping``.

docs/ros2.md has the mapping table, frames, QoS and an rclpy example.
"""
