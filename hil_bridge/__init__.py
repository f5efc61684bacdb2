"""hil_bridge: the echoloop bus (ROS 2-style topics over ZeroMQ), sim clock, server and tools."""
