"""The serial sonar-head edge (docs/spec/protocols.md §2; user guide in docs/serial.md).

Modules: ``framing`` (COBS + CRC-32 frames, streaming decoder), ``protocol`` (payloads, echo
encodings, chunking and reassembly), ``link`` (``open_link(url)``: reconnecting pyserial link
with raw capture), ``ptyport`` (device end of a pty), ``host`` (bus-free host session and the
link budget), ``adapter`` (``SonarHeadAdapter``, the ``sonar_head`` launch node).
"""
