"""drivers.dronecan: echoloop as DroneCAN peripherals of a stock flight controller.

* :mod:`~drivers.dronecan.interfaces`: CAN interfaces by URL (``mcast:N``, SocketCAN, SLCAN);
* :mod:`~drivers.dronecan.mcast`: CAN over UDP multicast (ArduPilot SITL's), in-process;
* :mod:`~drivers.dronecan.allocation`: dynamic node-ID allocation, the allocatee's side;
* :mod:`~drivers.dronecan.messages`: range finders, air data and GNSS out, actuator commands
  in: the one place this edge converts frames and units;
* :mod:`~drivers.dronecan.node`: :class:`~drivers.dronecan.node.DroneCanNode`, the launchable
  node.

DSDL and transfers are the ``dronecan`` package's. It may import :mod:`hil_bridge` and
:mod:`sim_core`; it knows nothing of the other drivers. Sensor physics comes from
:mod:`sim_core.sensors`.
"""
