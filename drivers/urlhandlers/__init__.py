"""pyserial URL handlers of echoloop: one ``protocol_<scheme>`` module per scheme (``sonarsim://``,
an in-process mock sonar head).

pyserial imports ``drivers.urlhandlers.protocol_<scheme>`` by name when ``serial_for_url`` opens
a URL of the scheme; :mod:`drivers.serial.link` puts this package on
``serial.protocol_handler_packages`` from its ``URL_HANDLERS`` table, without importing it.
A handler may import :mod:`drivers.mocks` (the device it plays), :mod:`drivers.serial`,
hil_bridge and sim_core; nothing imports this package but pyserial.
"""
