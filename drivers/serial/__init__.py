"""The serial sonar-head edge (docs/spec/protocols.md §2; user guide in docs/serial.md).

Modules: ``framing`` (COBS + CRC-32 frames, streaming decoder), ``protocol`` (payloads, echo
encodings, chunking and reassembly), ``link`` (``open_link(url)``: reconnecting pyserial link
with raw capture; the table of echoloop's own URL schemes), ``ptyport`` (a pty whose master side
plays the device), ``device_port`` (the device end of any serial link as a device program uses
it, and UART pacing), ``host`` (bus-free host session and the link budget), ``adapter``
(``SonarHeadAdapter``, the ``sonar_head`` launch node).

Host side: it may import :mod:`hil_bridge` and :mod:`sim_core`; never :mod:`drivers.can`,
:mod:`drivers.faults`, :mod:`drivers.mocks` or :mod:`drivers.urlhandlers` (the ``sonarsim://``
handler is registered by its package name and imported by pyserial only when opened).
"""
