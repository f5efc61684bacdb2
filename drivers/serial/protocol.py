"""Sonar-head message payloads (docs/spec/protocols.md §2) and the echo sample encodings.

All integers and floats are little-endian. Byte tables are in docs/serial.md.

* PING (head -> host, binding): ``ping_seq u16, az f32, el f32, beamwidth f32, encoding u8``.
* ECHO (host -> head, binding): ``ping_seq u16, chunk u16, n_chunks u16, encoding u8,
  channels u8, fs_hz u32, scale f32, n_samples u32`` then the chunk's sample bytes.
* CONFIG (head -> host), STATUS (both), HEARTBEAT (both), ERROR (both): this project's design.

Lockstep (docs/serial.md): a host HEARTBEAT with ``HEARTBEAT_LOCKSTEP`` in ``flags`` carries the
simulation's time in its frame header's ``stamp_ns``; a head that supports it then fires ping
``n`` at sim time ``n * ping_period_ns(ping_rate_mhz)``, stamps the PING frame with that time,
and fires the next one only once the echo of this one arrived.

Encodings (``Encoding``): ``INT16`` real samples (value = int16 x scale), ``IQ16`` complex
baseband I,Q int16 pairs (value = (I + jQ) x scale, centre frequency in CONFIG/STATUS),
``FLOAT32`` real samples (scale written as 1.0). Multi-channel samples are interleaved per
sample. The int16 scale is chosen per echo as ``max|x| / 32767`` (for IQ the max over both
components), rounded up in float32 so that no sample clips.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from drivers.serial.framing import MAX_PAYLOAD, wire_size

__all__ = [
    "CONFIG",
    "ECHO_HEADER",
    "ECHO_SAMPLE_BYTES",
    "ERROR",
    "HEARTBEAT",
    "HEARTBEAT_LOCKSTEP",
    "PING",
    "STATUS",
    "AssembledEcho",
    "ConfigPayload",
    "EchoAssembler",
    "EchoChunk",
    "EncodedEcho",
    "Encoding",
    "ErrorCode",
    "ErrorPayload",
    "HeartbeatPayload",
    "LinkState",
    "PingPayload",
    "StatusPayload",
    "chunk_echo",
    "decode_samples",
    "echo_wire_bytes",
    "encode_samples",
    "int16_scale",
    "ping_period_ns",
]


class Encoding(IntEnum):
    """Echo sample encodings of §2."""

    INT16 = 0
    IQ16 = 1
    FLOAT32 = 2

    @classmethod
    def parse(cls, value: int | str) -> Encoding:
        """Accept 0/1/2, ``"int16"``, ``"iq16"``/``"iq"``, ``"float32"`` (case-insensitive)."""
        if isinstance(value, str):
            key = value.strip().lower()
            names = {"int16": cls.INT16, "iq16": cls.IQ16, "iq": cls.IQ16, "float32": cls.FLOAT32}
            if key in names:
                return names[key]
            if key.isdigit():
                value = int(key)
            else:
                raise ValueError(f"encoding {value!r} unknown; expected one of {sorted(names)}")
        try:
            return cls(int(value))
        except ValueError:
            raise ValueError(f"encoding {value!r} unknown; expected 0, 1 or 2") from None


#: bytes per sample and channel on the wire
ECHO_SAMPLE_BYTES: dict[Encoding, int] = {Encoding.INT16: 2, Encoding.IQ16: 4, Encoding.FLOAT32: 4}

PING = struct.Struct("<HfffB")  # 15 bytes
ECHO_HEADER = struct.Struct("<HHHBBIfI")  # 20 bytes
CONFIG = struct.Struct("<BBBBIIIH")  # 18 bytes
STATUS = struct.Struct("<BBHIIIIII")  # 28 bytes
HEARTBEAT = struct.Struct("<IBB")  # 6 bytes (a 5-byte one without flags is accepted)
_HEARTBEAT_V1 = struct.Struct("<IB")
#: HEARTBEAT flags bit: the frame's stamp_ns is the host's sim time; ping on it (lockstep)
HEARTBEAT_LOCKSTEP = 0x01
ERROR = struct.Struct("<HH")  # 4 bytes + UTF-8 text
MAX_ERROR_TEXT = 200
#: CONFIG ranges a host accepts (docs/serial.md); a CONFIG outside them is refused
CONFIG_MAX_CHANNELS = 16
CONFIG_BAUD_RANGE = (1200, 20_000_000)
CONFIG_MAX_DECIMATION = 1000


def _payload_error(kind: str, data: bytes, size: int) -> ValueError:
    return ValueError(f"{kind} payload of {len(data)} bytes; expected {size}")


@dataclass(frozen=True, slots=True)
class PingPayload:
    """A ping the head just emitted (angles in rad, relative to the body's forward axis)."""

    ping_seq: int
    az: float
    el: float
    beamwidth: float
    encoding: Encoding

    def pack(self) -> bytes:
        return PING.pack(self.ping_seq & 0xFFFF, self.az, self.el, self.beamwidth,
                         int(self.encoding))

    @classmethod
    def unpack(cls, data: bytes) -> PingPayload:
        if len(data) != PING.size:
            raise _payload_error("PING", data, PING.size)
        seq, az, el, bw, enc = PING.unpack(data)
        return cls(seq, az, el, bw, Encoding.parse(enc))


@dataclass(frozen=True, slots=True)
class EchoChunk:
    """One ECHO payload: header fields plus this chunk's sample bytes."""

    ping_seq: int
    chunk: int
    n_chunks: int
    encoding: Encoding
    channels: int
    fs_hz: int
    scale: float
    n_samples: int
    data: bytes

    def pack(self) -> bytes:
        head = ECHO_HEADER.pack(self.ping_seq & 0xFFFF, self.chunk, self.n_chunks,
                                int(self.encoding), self.channels, self.fs_hz, self.scale,
                                self.n_samples)
        return head + self.data

    @classmethod
    def unpack(cls, data: bytes) -> EchoChunk:
        if len(data) < ECHO_HEADER.size:
            raise ValueError(f"ECHO payload of {len(data)} bytes is shorter than its "
                             f"{ECHO_HEADER.size}-byte header")
        seq, chunk, n_chunks, enc, ch, fs, scale, n = ECHO_HEADER.unpack_from(data)
        encoding = Encoding.parse(enc)
        if n_chunks == 0 or chunk >= n_chunks:
            raise ValueError(f"ECHO chunk {chunk} of {n_chunks}")
        if ch == 0:
            raise ValueError("ECHO with 0 channels")
        body = data[ECHO_HEADER.size:]
        if len(body) % (ch * ECHO_SAMPLE_BYTES[encoding]):
            raise ValueError(f"ECHO chunk of {len(body)} bytes is not whole samples of "
                             f"{ch} channel(s) x {ECHO_SAMPLE_BYTES[encoding]} bytes")
        return cls(seq, chunk, n_chunks, encoding, ch, fs, scale, n, body)


@dataclass(frozen=True, slots=True)
class ConfigPayload:
    """What the head wants (head -> host, on connect and on change).

    ``ping_rate_mhz`` is the ping rate in milli-hertz, ``baudrate`` the head's UART rate (0 =
    unknown), ``f_center_hz``/``decimation`` the IQ baseband it wants (0 = host default).
    """

    encoding: Encoding
    channels: int
    ping_rate_mhz: int
    baudrate: int
    f_center_hz: int
    decimation: int
    proto_version: int = 1
    flags: int = 0

    def pack(self) -> bytes:
        return CONFIG.pack(self.proto_version, int(self.encoding), self.channels, self.flags,
                           self.ping_rate_mhz, self.baudrate, self.f_center_hz, self.decimation)

    @classmethod
    def unpack(cls, data: bytes) -> ConfigPayload:
        if len(data) != CONFIG.size:
            raise _payload_error("CONFIG", data, CONFIG.size)
        ver, enc, ch, flags, rate, baud, fc, dec = CONFIG.unpack(data)
        return cls(Encoding.parse(enc), ch, rate, baud, fc, dec, ver, flags)

    def problems(self, echo_fs_hz: int) -> list[str]:
        """Every field out of its range (docs/serial.md, CONFIG), as ``"name value: rule"``;
        empty when the CONFIG can be applied to echoes sampled at ``echo_fs_hz``."""
        out: list[str] = []

        def check(name: str, value: int, ok: bool, rule: str) -> None:
            if not ok:
                out.append(f"{name} {value}: {rule}")

        check("proto_version", self.proto_version, self.proto_version == 1, "expected 1")
        check("channels", self.channels, 1 <= self.channels <= CONFIG_MAX_CHANNELS,
              f"expected 1..{CONFIG_MAX_CHANNELS}")
        check("flags", self.flags, self.flags == 0, "reserved, expected 0")
        check("ping_rate_mhz", self.ping_rate_mhz, self.ping_rate_mhz <= 1_000_000,
              "expected 0 (unknown) or up to 1000000 (1 kHz)")
        check("baudrate", self.baudrate,
              self.baudrate == 0 or CONFIG_BAUD_RANGE[0] <= self.baudrate <= CONFIG_BAUD_RANGE[1],
              f"expected 0 (unknown) or {CONFIG_BAUD_RANGE[0]}..{CONFIG_BAUD_RANGE[1]}")
        nyquist = echo_fs_hz // 2
        check("f_center_hz", self.f_center_hz, self.f_center_hz < nyquist,
              f"expected 0 (host default) or below the echo's Nyquist rate {nyquist} Hz")
        check("decimation", self.decimation,
              self.decimation == 0 or (self.decimation <= CONFIG_MAX_DECIMATION
                                       and echo_fs_hz % self.decimation == 0),
              f"expected 0 (host default) or 1..{CONFIG_MAX_DECIMATION} dividing the echo "
              f"rate {echo_fs_hz} Hz (the baseband rate must be a whole number of Hz)")
        return out


class LinkState(IntEnum):
    """``state`` of a STATUS payload."""

    OK = 0
    DEGRADED = 1  # frames are being dropped
    OVER_BUDGET = 2  # the baud rate cannot carry the configured ping rate and encoding


@dataclass(frozen=True, slots=True)
class StatusPayload:
    """Sender's state and counters (u32 counters wrap modulo 2**32)."""

    state: int
    encoding: Encoding
    decimation: int
    f_center_hz: int
    frames_rx: int
    frames_tx: int
    crc_errors: int
    dropped: int
    reconnects: int

    def pack(self) -> bytes:
        m = 0xFFFFFFFF
        return STATUS.pack(self.state, int(self.encoding), self.decimation, self.f_center_hz,
                           self.frames_rx & m, self.frames_tx & m, self.crc_errors & m,
                           self.dropped & m, self.reconnects & m)

    @classmethod
    def unpack(cls, data: bytes) -> StatusPayload:
        if len(data) != STATUS.size:
            raise _payload_error("STATUS", data, STATUS.size)
        st, enc, dec, fc, rx, tx, crc, drop, rec = STATUS.unpack(data)
        return cls(st, Encoding.parse(enc), dec, fc, rx, tx, crc, drop, rec)


@dataclass(frozen=True, slots=True)
class HeartbeatPayload:
    """Liveness (both directions, 1 Hz; from a lockstep host also at every sim tick): sender
    uptime in ms (wraps), a LinkState and ``flags`` (``HEARTBEAT_LOCKSTEP``)."""

    uptime_ms: int
    state: int = 0
    flags: int = 0

    @property
    def lockstep(self) -> bool:
        return bool(self.flags & HEARTBEAT_LOCKSTEP)

    def pack(self) -> bytes:
        return HEARTBEAT.pack(self.uptime_ms & 0xFFFFFFFF, self.state, self.flags)

    @classmethod
    def unpack(cls, data: bytes) -> HeartbeatPayload:
        if len(data) == _HEARTBEAT_V1.size:
            return cls(*_HEARTBEAT_V1.unpack(data))
        if len(data) != HEARTBEAT.size:
            raise _payload_error("HEARTBEAT", data, HEARTBEAT.size)
        return cls(*HEARTBEAT.unpack(data))


def ping_period_ns(ping_rate_mhz: int) -> int:
    """Sim nanoseconds between pings of a head whose CONFIG says ``ping_rate_mhz`` (mHz)."""
    if ping_rate_mhz <= 0:
        raise ValueError(f"ping_rate_mhz {ping_rate_mhz!r} must be > 0")
    return round(1e12 / ping_rate_mhz)


class ErrorCode(IntEnum):
    """``code`` of an ERROR payload."""

    BAD_PAYLOAD = 1  # a frame passed CRC but its payload did not parse
    UNSUPPORTED_ENCODING = 2
    OVER_BUDGET = 3
    ECHO_INCOMPLETE = 4
    NO_ECHO = 5  # no echo for this ping (e.g. no simulator answered in time)
    BAD_CONFIG = 6  # a CONFIG with a field out of range: refused, the previous one stays


@dataclass(frozen=True, slots=True)
class ErrorPayload:
    """An error report: code, the seq (frame seq or ping_seq) it refers to, UTF-8 text."""

    code: int
    ref_seq: int
    text: str = ""

    def pack(self) -> bytes:
        text = self.text.encode("utf-8")[:MAX_ERROR_TEXT]
        return ERROR.pack(self.code, self.ref_seq & 0xFFFF) + text

    @classmethod
    def unpack(cls, data: bytes) -> ErrorPayload:
        if len(data) < ERROR.size:
            raise _payload_error("ERROR", data, ERROR.size)
        code, ref = ERROR.unpack_from(data)
        return cls(code, ref, data[ERROR.size:].decode("utf-8", errors="replace"))


# ---- sample encodings -------------------------------------------------------------------------


def int16_scale(max_abs: float) -> float:
    """Smallest float32 scale with ``max_abs / scale <= 32767`` (1.0 for an all-zero echo)."""
    if not np.isfinite(max_abs) or max_abs < 0:
        raise ValueError(f"max |sample| {max_abs!r} must be finite and >= 0")
    if max_abs == 0.0:
        return 1.0
    tiny = np.float32(np.finfo(np.float32).smallest_subnormal)
    scale = max(np.float32(max_abs / 32767.0), tiny)
    if not np.isfinite(scale):
        raise ValueError(f"max |sample| {max_abs!r} too large for a float32 scale")
    while max_abs / float(scale) > 32767.0:
        scale = np.nextafter(scale, np.float32(np.inf))
    return float(scale)


@dataclass(frozen=True, slots=True)
class EncodedEcho:
    """One whole echo in wire form (before chunking)."""

    encoding: Encoding
    channels: int
    fs_hz: int
    scale: float
    n_samples: int
    data: bytes


def _as_channels(samples: NDArray[np.generic]) -> NDArray[np.generic]:
    a = np.asarray(samples)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[0] == 0 or a.shape[0] > 255:
        raise ValueError(f"samples of shape {np.shape(samples)}; expected (N,) or (C, N), C<=255")
    return a


def encode_samples(samples: NDArray[np.generic], fs_hz: float, encoding: Encoding) -> EncodedEcho:
    """Encode real samples (N,)/(C,N) for INT16/FLOAT32, complex baseband for IQ16.

    ``fs_hz`` is the rate of ``samples`` (for IQ16 the baseband rate) and must be a whole
    number of hertz (the wire field is u32).
    """
    encoding = Encoding.parse(encoding)
    fs_int = round(float(fs_hz))
    if abs(fs_int - float(fs_hz)) > 1e-6 * max(1.0, float(fs_hz)) or not 0 < fs_int < 1 << 32:
        raise ValueError(f"fs_hz {fs_hz!r} must be a whole number of Hz in 1..2**32-1")
    a = _as_channels(samples)
    channels, n = a.shape
    if encoding is Encoding.IQ16:
        z = a.astype(np.complex128, copy=False)
        parts = np.stack([z.real, z.imag], axis=-1)  # (C, N, 2)
        max_abs = float(np.max(np.abs(parts))) if parts.size else 0.0
        scale = int16_scale(max_abs)
        q = np.clip(np.rint(parts / scale), -32767, 32767).astype("<i2")
        data = np.ascontiguousarray(q.transpose(1, 0, 2)).tobytes()
    else:
        if np.iscomplexobj(a):
            raise ValueError(f"complex samples need encoding IQ16, not {encoding.name}")
        x = a.astype(np.float64, copy=False)
        if not np.all(np.isfinite(x)):
            raise ValueError("samples contain NaN or infinity")
        if encoding is Encoding.INT16:
            max_abs = float(np.max(np.abs(x))) if x.size else 0.0
            scale = int16_scale(max_abs)
            q = np.clip(np.rint(x / scale), -32767, 32767).astype("<i2")
            data = np.ascontiguousarray(q.T).tobytes()
        else:
            f = x.astype("<f4")
            if not np.all(np.isfinite(f)):
                raise ValueError("samples exceed the float32 range")
            scale = 1.0
            data = np.ascontiguousarray(f.T).tobytes()
    return EncodedEcho(encoding, channels, fs_int, scale, n, data)


def decode_samples(
    data: bytes, encoding: Encoding, channels: int, scale: float
) -> NDArray[np.float64] | NDArray[np.complex128]:
    """Inverse of :func:`encode_samples`: (C, N) float64 (complex128 for IQ16)."""
    encoding = Encoding.parse(encoding)
    if encoding is Encoding.IQ16:
        q = np.frombuffer(data, dtype="<i2").reshape(-1, channels, 2).astype(np.float64)
        return np.ascontiguousarray((q[..., 0] + 1j * q[..., 1]).T) * scale
    dtype = "<i2" if encoding is Encoding.INT16 else "<f4"
    x = np.frombuffer(data, dtype=dtype).reshape(-1, channels).astype(np.float64)
    return np.ascontiguousarray(x.T) * (scale if encoding is Encoding.INT16 else 1.0)


def chunk_echo(ping_seq: int, echo: EncodedEcho) -> list[EchoChunk]:
    """Split an encoded echo into ECHO payloads of at most 4096 bytes, whole samples each."""
    frame = echo.channels * ECHO_SAMPLE_BYTES[echo.encoding]
    per_chunk = (MAX_PAYLOAD - ECHO_HEADER.size) // frame * frame
    pieces = [echo.data[i:i + per_chunk] for i in range(0, len(echo.data), per_chunk)] or [b""]
    if len(pieces) > 0xFFFF:
        raise ValueError(f"echo needs {len(pieces)} chunks; at most 65535 fit the chunk field")
    return [
        EchoChunk(ping_seq & 0xFFFF, i, len(pieces), echo.encoding, echo.channels, echo.fs_hz,
                  echo.scale, echo.n_samples, piece)
        for i, piece in enumerate(pieces)
    ]


def echo_wire_bytes(n_samples: int, channels: int, encoding: Encoding) -> int:
    """Bytes on the wire (framing included, COBS worst case) for one whole echo."""
    frame = channels * ECHO_SAMPLE_BYTES[Encoding.parse(encoding)]
    total = n_samples * frame
    per_chunk = (MAX_PAYLOAD - ECHO_HEADER.size) // frame * frame
    full, rest = divmod(total, per_chunk)
    size = full * wire_size(ECHO_HEADER.size + per_chunk)
    if rest or not full:
        size += wire_size(ECHO_HEADER.size + rest)
    return size


@dataclass(frozen=True, slots=True)
class AssembledEcho:
    """A complete echo: (C, N) samples (complex for IQ16) and its metadata."""

    ping_seq: int
    encoding: Encoding
    fs_hz: int
    scale: float
    samples: NDArray[np.float64] | NDArray[np.complex128]


class EchoAssembler:
    """Reassembles ECHO chunks by (ping_seq, chunk); checks order, consistency, completeness.

    Chunks are sent in order, so an echo is complete when chunk ``n_chunks-1`` arrives after
    every earlier chunk with identical metadata and the byte count matches ``n_samples``. A
    gap, a metadata change or a new ping_seq before completion abandons the partial echo and
    counts it in ``incomplete``; a chunk repeated with the same index counts in ``duplicates``.
    """

    def __init__(self) -> None:
        self._key: tuple[int, int, int, int, int, float, int] | None = None
        self._abandoned: tuple[int, int, int, int, int, float, int] | None = None
        self._next = 0
        self._parts: list[bytes] = []
        self.complete = 0
        self.incomplete = 0
        self.duplicates = 0
        #: ping_seq of the echo most recently counted in ``incomplete`` (any of the reasons)
        self.last_incomplete_ping: int | None = None

    @property
    def last_abandoned_ping(self) -> int | None:
        """ping_seq of the most recently abandoned partial echo (None if none yet)."""
        return None if self._abandoned is None else self._abandoned[0]

    def stats(self) -> dict[str, int]:
        return {"echoes_complete": self.complete, "echoes_incomplete": self.incomplete,
                "chunk_duplicates": self.duplicates}

    def _abandon(self) -> None:
        if self._key is not None:
            self.incomplete += 1
            self._abandoned = self._key
            self.last_incomplete_ping = self._key[0]
        self._key, self._next, self._parts = None, 0, []

    def flush(self) -> None:
        """Abandon (and count) a partial echo, e.g. after a reconnect."""
        self._abandon()

    def feed(self, c: EchoChunk) -> AssembledEcho | None:
        key = (c.ping_seq, c.n_chunks, int(c.encoding), c.channels, c.fs_hz, c.scale, c.n_samples)
        if self._key == key and c.chunk < self._next:
            self.duplicates += 1
            return None
        if self._key is not None and (key != self._key or c.chunk != self._next):
            self._abandon()
        if self._key is None:
            if c.chunk != 0:
                if c.chunk == c.n_chunks - 1 and key != self._abandoned:
                    self.incomplete += 1  # an echo whose first chunk(s) never arrived
                    self.last_incomplete_ping = c.ping_seq
                return None
            self._key = key
        self._parts.append(c.data)
        self._next += 1
        if self._next < c.n_chunks:
            return None
        data = b"".join(self._parts)
        self._key, self._next, self._parts = None, 0, []
        if len(data) != c.n_samples * c.channels * ECHO_SAMPLE_BYTES[c.encoding]:
            self.incomplete += 1
            self.last_incomplete_ping = c.ping_seq
            return None
        self.complete += 1
        return AssembledEcho(c.ping_seq, c.encoding, c.fs_hz, c.scale,
                             decode_samples(data, c.encoding, c.channels, c.scale))

