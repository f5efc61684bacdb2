"""CAN glider autopilot edge: the "raw" profile (``glider.dbc``), its codec, a resilient
python-can link and the ``AutopilotAdapter`` node (docs/can.md).

Modules: :mod:`drivers.can.codec` (cantools, node-id offsets, saturation counting),
:mod:`drivers.can.bus` (``CanLink``: retry, back-off, bus-off recovery, candump logging),
:mod:`drivers.can.adapter` (``AutopilotAdapter``, launch node ``autopilot``) and
:mod:`drivers.can.busload` (on-wire frame length and bus load).
"""
