"""Sonar-head serial framing (docs/spec/protocols.md §2): COBS + CRC-32 + the 14-byte header.

Wire form of one frame::

    COBS( body || crc32(body) as u32 little-endian ) || 0x00
    body = header (14 bytes, little-endian) || payload (payload_len <= 4096 bytes)
    header = version u8 (=1), msg_type u8, seq u16, stamp_ns u64, payload_len u16

:func:`encode_frame` builds the wire bytes of one body; :class:`FrameDecoder` is the streaming
receiver. The decoder contract (binding):

1. ``feed(data)`` accepts any bytes (any split, any garbage) and returns the frames completed by
   them, in order; it never raises.
2. A frame whose COBS, CRC, length, version or message type is wrong is dropped and counted under
   exactly one reason; decoding resumes after the next ``0x00``.
3. Bytes with no ``0x00`` for longer than the largest legal frame are discarded (``oversize``),
   so memory stays bounded whatever arrives.
4. Empty frames (consecutive ``0x00``) are idle/sync bytes: ignored, not errors.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum

from cobs import cobs

__all__ = [
    "CRC_SIZE",
    "HEADER",
    "HEADER_SIZE",
    "MAX_PAYLOAD",
    "MAX_WIRE_FRAME",
    "VERSION",
    "Frame",
    "FrameDecoder",
    "MsgType",
    "encode_frame",
    "frame_bytes",
    "pack_header",
    "unpack_header",
    "wire_size",
]

VERSION = 1
HEADER = struct.Struct("<BBHQH")
HEADER_SIZE = HEADER.size  # 14
CRC_SIZE = 4
MAX_PAYLOAD = 4096
_MAX_COBS_IN = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE
#: Largest legal frame on the wire: COBS adds one byte per started 254-byte block, plus the 0x00.
MAX_WIRE_FRAME = _MAX_COBS_IN + (_MAX_COBS_IN + 253) // 254 + 1


class MsgType(IntEnum):
    """Message types of §2 (direction in brackets)."""

    PING = 0x01  # head -> host
    ECHO = 0x02  # host -> head
    CONFIG = 0x03  # head -> host
    STATUS = 0x04  # both
    HEARTBEAT = 0x05  # both
    ERROR = 0x7F  # both


_KNOWN_TYPES = frozenset(int(t) for t in MsgType)


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded frame: header fields and the raw payload bytes."""

    msg_type: int
    seq: int
    stamp_ns: int
    payload: bytes

    def body(self) -> bytes:
        """Header || payload, as covered by the CRC."""
        return pack_header(self.msg_type, self.seq, self.stamp_ns, len(self.payload)) + self.payload


def pack_header(msg_type: int, seq: int, stamp_ns: int, payload_len: int) -> bytes:
    """The 14 header bytes; raises ValueError naming a field outside its range."""
    if int(msg_type) not in _KNOWN_TYPES:
        raise ValueError(f"msg_type {msg_type!r} unknown; expected one of {sorted(_KNOWN_TYPES)}")
    if not 0 <= seq <= 0xFFFF:
        raise ValueError(f"seq {seq!r} outside uint16 0..65535")
    if not 0 <= stamp_ns < 1 << 64:
        raise ValueError(f"stamp_ns {stamp_ns!r} outside uint64")
    if not 0 <= payload_len <= MAX_PAYLOAD:
        raise ValueError(f"payload_len {payload_len!r} outside 0..{MAX_PAYLOAD}")
    return HEADER.pack(VERSION, int(msg_type), seq, stamp_ns, payload_len)


def unpack_header(body: bytes) -> tuple[int, int, int, int, int]:
    """``(version, msg_type, seq, stamp_ns, payload_len)`` of the first 14 bytes of ``body``."""
    if len(body) < HEADER_SIZE:
        raise ValueError(f"body of {len(body)} bytes is shorter than the {HEADER_SIZE}-byte header")
    version, msg_type, seq, stamp_ns, payload_len = HEADER.unpack_from(body)
    return version, msg_type, seq, stamp_ns, payload_len


def encode_frame(body: bytes) -> bytes:
    """Wire bytes of one frame: ``COBS(body || crc32(body) LE) || 0x00``."""
    if len(body) > HEADER_SIZE + MAX_PAYLOAD:
        raise ValueError(f"body of {len(body)} bytes exceeds {HEADER_SIZE + MAX_PAYLOAD}")
    crc = zlib.crc32(body) & 0xFFFFFFFF
    return cobs.encode(bytes(body) + crc.to_bytes(4, "little")) + b"\x00"


def frame_bytes(msg_type: int, seq: int, stamp_ns: int, payload: bytes) -> bytes:
    """Header + payload framed for the wire (the usual way to send one message)."""
    return encode_frame(pack_header(msg_type, seq, stamp_ns, len(payload)) + bytes(payload))


def wire_size(payload_len: int) -> int:
    """Exact bytes on the wire for a frame with a payload of ``payload_len`` bytes.

    COBS adds one byte per started 254-byte run of non-zero bytes; the worst case (no zeros) is
    ``ceil(n/254)``. Every payload here holds zeros, so this worst case is an upper bound that
    is tight within a few bytes; it is what the link budget uses.
    """
    n = HEADER_SIZE + payload_len + CRC_SIZE
    return n + max(1, (n + 253) // 254) + 1


class FrameDecoder:
    """Streaming decoder of the §2 framing (contract in the module docstring)."""

    _REASONS = ("cobs_errors", "length_errors", "crc_errors", "version_errors", "type_errors")

    def __init__(self) -> None:
        self._buf = bytearray()
        self._discarding = False
        self.frames_ok = 0
        self.bytes_in = 0
        self.oversize = 0
        self.cobs_errors = 0
        self.length_errors = 0
        self.crc_errors = 0
        self.version_errors = 0
        self.type_errors = 0

    @property
    def dropped(self) -> int:
        """Frames dropped for any reason (oversize runs count once each)."""
        return self.oversize + sum(getattr(self, r) for r in self._REASONS)

    def stats(self) -> dict[str, int]:
        out = {"frames_ok": self.frames_ok, "bytes_in": self.bytes_in, "oversize": self.oversize}
        out.update({r: getattr(self, r) for r in self._REASONS})
        out["dropped"] = self.dropped
        return out

    def reset(self) -> None:
        """Forget a partial frame (after a reconnect); counters are kept."""
        self._buf.clear()
        self._discarding = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Frames completed by ``data``; corrupt ones are dropped and counted, never raised."""
        if isinstance(data, memoryview):
            data = data.tobytes()
        self.bytes_in += len(data)
        frames: list[Frame] = []
        view = memoryview(data)
        start = 0
        n = len(view)
        while start < n:
            end = data.find(b"\x00", start)
            if end < 0:
                self._append(view[start:])
                break
            if self._discarding:
                self._discarding = False
                self._buf.clear()
            else:
                self._buf += view[start:end]
                if len(self._buf) > MAX_WIRE_FRAME:
                    self.oversize += 1
                elif self._buf:
                    frame = self._decode(bytes(self._buf))
                    if frame is not None:
                        frames.append(frame)
                self._buf.clear()
            start = end + 1
        return frames

    def _append(self, chunk: memoryview) -> None:
        if self._discarding:
            return
        self._buf += chunk
        if len(self._buf) > MAX_WIRE_FRAME:
            self.oversize += 1
            self._buf.clear()
            self._discarding = True

    def _decode(self, encoded: bytes) -> Frame | None:
        try:
            raw = cobs.decode(encoded)
        except cobs.DecodeError:
            self.cobs_errors += 1
            return None
        if len(raw) < HEADER_SIZE + CRC_SIZE:
            self.length_errors += 1
            return None
        body, crc = raw[:-CRC_SIZE], raw[-CRC_SIZE:]
        if zlib.crc32(body) & 0xFFFFFFFF != int.from_bytes(crc, "little"):
            self.crc_errors += 1
            return None
        version, msg_type, seq, stamp_ns, payload_len = HEADER.unpack_from(body)
        if version != VERSION:
            self.version_errors += 1
            return None
        if payload_len > MAX_PAYLOAD or payload_len != len(body) - HEADER_SIZE:
            self.length_errors += 1
            return None
        if msg_type not in _KNOWN_TYPES:
            self.type_errors += 1
            return None
        self.frames_ok += 1
        return Frame(msg_type, seq, stamp_ns, body[HEADER_SIZE:])
