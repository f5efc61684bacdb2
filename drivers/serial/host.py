"""Host side of the sonar-head protocol, independent of the bus: link budget and session.

:func:`link_budget` answers "can this baud rate carry this ping rate and encoding?" with exact
frame sizes. :class:`SonarHeadHost` owns one :class:`~drivers.serial.link.Link`, decodes what
the head sends (PING, CONFIG, STATUS, HEARTBEAT, ERROR), and turns echoes into ECHO chunks in
the encoding each ping asked for. :class:`drivers.serial.adapter.SonarHeadAdapter` wires it to
the bus; tests and benchmarks drive it directly.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.serial.framing import Frame, FrameDecoder, MsgType, frame_bytes, wire_size
from drivers.serial.link import Link
from drivers.serial.protocol import (
    CONFIG,
    ECHO_SAMPLE_BYTES,
    HEARTBEAT,
    HEARTBEAT_LOCKSTEP,
    MAX_ERROR_TEXT,
    PING,
    STATUS,
    ConfigPayload,
    Encoding,
    ErrorCode,
    ErrorPayload,
    HeartbeatPayload,
    LinkState,
    PingPayload,
    StatusPayload,
    chunk_echo,
    echo_wire_bytes,
    encode_samples,
)
from hil_bridge.bus.faults import Faults
from sim_core.sonar import to_baseband

__all__ = ["LinkBudget", "SonarHeadHost", "baseband", "link_budget"]

log = logging.getLogger(__name__)

#: bits per byte on an 8N1 UART (start + 8 data + stop)
BITS_PER_BYTE = 10


@dataclass(frozen=True, slots=True)
class LinkBudget:
    """Bytes per second each way against the UART capacity (8N1)."""

    baudrate: int
    encoding: Encoding
    ping_rate_hz: float
    samples_per_echo: int  # per channel, after decimation for IQ16
    channels: int
    echo_wire_bytes: int  # one echo, framing included
    sample_bytes: int  # one echo, samples only
    down_bytes_per_s: float  # host -> head: echoes + STATUS + HEARTBEAT
    up_bytes_per_s: float  # head -> host: PINGs + CONFIG + HEARTBEAT
    capacity_bytes_per_s: float

    @property
    def utilisation(self) -> float:
        """Fraction of the busier direction's capacity in use (> 1: does not fit)."""
        return max(self.down_bytes_per_s, self.up_bytes_per_s) / self.capacity_bytes_per_s

    @property
    def framing_overhead(self) -> float:
        """Framing bytes (header, ECHO header, CRC, COBS, delimiter) / sample bytes."""
        return (self.echo_wire_bytes - self.sample_bytes) / max(1, self.sample_bytes)

    @property
    def fits(self) -> bool:
        return self.utilisation <= 1.0

    def describe(self) -> str:
        return (
            f"{self.ping_rate_hz:g} pings/s x {self.echo_wire_bytes} B/echo "
            f"({self.encoding.name}, {self.channels} ch x {self.samples_per_echo} samples) = "
            f"{self.down_bytes_per_s:.0f} B/s of {self.capacity_bytes_per_s:.0f} B/s at "
            f"{self.baudrate} baud ({100 * self.utilisation:.1f} %)"
        )


def link_budget(
    *, baudrate: int, ping_rate_hz: float, echo_samples: int, channels: int = 1,
    encoding: Encoding | int | str = Encoding.INT16, decimation: int = 1,
    heartbeat_hz: float = 1.0,
) -> LinkBudget:
    """Budget of one sonar head link; ``echo_samples`` per channel at the echo's own rate."""
    enc = Encoding.parse(encoding)
    if baudrate <= 0 or ping_rate_hz <= 0 or echo_samples < 0 or channels < 1:
        raise ValueError(
            f"link budget needs baudrate > 0, ping_rate_hz > 0, echo_samples >= 0, channels >= 1;"
            f" got {baudrate!r}, {ping_rate_hz!r}, {echo_samples!r}, {channels!r}"
        )
    if enc is Encoding.IQ16 and decimation < 1:
        raise ValueError(f"decimation {decimation!r} must be >= 1 for IQ16")
    n = math.ceil(echo_samples / decimation) if enc is Encoding.IQ16 else echo_samples
    per_echo = echo_wire_bytes(n, channels, enc)
    sample_bytes = n * channels * ECHO_SAMPLE_BYTES[enc]
    down = ping_rate_hz * per_echo + heartbeat_hz * (wire_size(HEARTBEAT.size)
                                                     + wire_size(STATUS.size))
    up = ping_rate_hz * wire_size(PING.size) + heartbeat_hz * (wire_size(HEARTBEAT.size)
                                                                + wire_size(CONFIG.size))
    return LinkBudget(int(baudrate), enc, float(ping_rate_hz), n, channels, per_echo,
                      sample_bytes, down, up, baudrate / BITS_PER_BYTE)


def baseband(
    samples: NDArray[np.floating[Any]], fs: float, f_center_hz: float, decimation: int
) -> tuple[NDArray[np.complexfloating[Any, Any]], float]:
    """Complex baseband of real echo samples (..., N) via ``sim_core.sonar.to_baseband``."""
    iq, fs_out = to_baseband(samples, fs, f_center_hz, int(decimation))
    return np.asarray(iq), float(fs_out)


class SonarHeadHost:
    """One head on one serial link: decode its frames, send it echoes, keep counters.

    ``on_ping(ping, frame)`` runs on the link's reader thread for each valid PING. A CONFIG
    with a field out of range (:meth:`ConfigPayload.problems`, for echoes sampled at
    ``echo_fs_hz``) is refused with an ERROR frame (``BAD_CONFIG``, counted
    ``configs_refused``) and the previous configuration stays.
    ``send_echo`` may be called from any thread; chunks of one echo are queued contiguously.
    ``faults``: where its link reports (:class:`~drivers.serial.link.Link`).
    """

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = 921600,
        encoding: Encoding | int | str = Encoding.INT16,
        f_center_hz: int = 70000,
        decimation: int = 20,
        follow_head_config: bool = True,
        capture: str | Path | None = None,
        overwrite: bool = False,
        on_ping: Callable[[PingPayload, Frame], None] | None = None,
        on_config: Callable[[ConfigPayload], None] | None = None,
        backoff_initial_s: float = 0.05,
        backoff_max_s: float = 2.0,
        tx_queue_bytes: int = 256 * 1024,
        echo_fs_hz: int = 400_000,
        name: str = "sonar_head",
        faults: Faults | None = None,
    ) -> None:
        self.name = name
        if not 0 < echo_fs_hz < 1 << 32:
            raise ValueError(f"echo_fs_hz {echo_fs_hz!r} must be in 1..2**32-1")
        self.echo_fs_hz = int(echo_fs_hz)
        self.encoding = Encoding.parse(encoding)
        if not 0 < f_center_hz < 1 << 32 or not 1 <= decimation <= 0xFFFF:
            raise ValueError(f"f_center_hz {f_center_hz!r} must be in 1..2**32-1 and "
                             f"decimation {decimation!r} in 1..65535")
        self.f_center_hz = int(f_center_hz)
        self.decimation = int(decimation)
        self.follow_head_config = follow_head_config
        self._on_ping = on_ping
        self._on_config = on_config
        self.decoder = FrameDecoder()
        self.link = Link(port, baudrate=baudrate, on_bytes=self._on_bytes,
                         on_connect=self._on_connect, capture=capture, overwrite=overwrite,
                         backoff_initial_s=backoff_initial_s, backoff_max_s=backoff_max_s,
                         tx_queue_bytes=tx_queue_bytes, name=name, faults=faults)
        self._tx_lock = threading.Lock()
        self._seq = 0
        self._t0 = time.monotonic()
        self._ping_encoding: collections.OrderedDict[int, Encoding] = collections.OrderedDict()
        self.head_config: ConfigPayload | None = None
        self.head_status: StatusPayload | None = None
        self.head_errors: collections.deque[ErrorPayload] = collections.deque(maxlen=32)
        self.last_head_heartbeat: float | None = None
        self.state = LinkState.OK
        self._dropped_seen = 0
        self.counts = collections.Counter[str]()
        self._rx_cv = threading.Condition()

    # ---- lifecycle -------------------------------------------------------------------------

    def start(self) -> None:
        self.link.start()

    def stop(self) -> None:
        self.link.stop()

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "frames_in": self.decoder.frames_ok,
            "frames_out": self.counts["frames_out"],
            "crc_errors": self.decoder.crc_errors,
            "dropped": self.decoder.dropped + self.counts["echoes_dropped"],
            "reconnects": self.link.reconnects,
            "state": int(self.state),
        }
        out.update({k: v for k, v in dict(self.counts).items() if k not in out})
        out.update({f"decoder_{k}": v for k, v in self.decoder.stats().items()})
        out.update({f"link_{k}": v for k, v in self.link.stats().items()})
        return out

    # ---- sending ---------------------------------------------------------------------------

    def _frame(self, msg_type: MsgType, payload: bytes, stamp_ns: int) -> bytes:
        data = frame_bytes(msg_type, self._seq, stamp_ns & 0xFFFFFFFFFFFFFFFF, payload)
        self._seq = (self._seq + 1) & 0xFFFF
        return data

    def send(self, msg_type: MsgType, payload: bytes, stamp_ns: int = 0) -> bool:
        with self._tx_lock:  # also serialises the sending threads' counter updates
            ok = self.link.send(self._frame(msg_type, payload, stamp_ns))
            self.counts["frames_out" if ok else "frames_out_dropped"] += 1
        return ok

    def requested_encoding(self, ping_seq: int) -> Encoding:
        """The encoding the head asked for in PING ``ping_seq`` (else the configured one)."""
        return self._ping_encoding.get(ping_seq & 0xFFFF, self.encoding)

    def send_echo(
        self, ping_seq: int, samples: NDArray[np.floating[Any]], fs: float, *,
        stamp_ns: int = 0, encoding: Encoding | None = None,
    ) -> int:
        """Encode one echo ((N,) or (C, N) real at ``fs``) and queue its chunks; returns count.

        Returns 0 (and counts ``echoes_dropped``) when the link is down or its queue is full.
        """
        enc = self.requested_encoding(ping_seq) if encoding is None else Encoding.parse(encoding)
        if enc is Encoding.IQ16:
            iq, fs_out = baseband(samples, fs, self.f_center_hz, self.decimation)
            encoded = encode_samples(iq, fs_out, enc)
        else:
            encoded = encode_samples(samples, fs, enc)
        chunks = chunk_echo(ping_seq, encoded)
        with self._tx_lock:
            blob = b"".join(self._frame(MsgType.ECHO, c.pack(), stamp_ns) for c in chunks)
            ok = self.link.send(blob)
            if not ok:
                self.counts["echoes_dropped"] += 1
                return 0
            self.counts["frames_out"] += len(chunks)
            self.counts["echoes_out"] += 1
            self.counts["echo_bytes_out"] += len(blob)
        return len(chunks)

    def update_state(self) -> LinkState:
        """DEGRADED while frames were dropped since the last call, OK again once none are;
        OVER_BUDGET is kept until the budget fits (set by the owner)."""
        dropped = self.decoder.dropped
        if self.state != LinkState.OVER_BUDGET:
            self.state = LinkState.DEGRADED if dropped > self._dropped_seen else LinkState.OK
        self._dropped_seen = dropped
        return self.state

    def send_heartbeat(self, *, stamp_ns: int = 0, lockstep: bool = False) -> None:
        """HEARTBEAT; ``lockstep``: flagged, with the sim time ``stamp_ns`` the head pings on."""
        uptime = int((time.monotonic() - self._t0) * 1e3)
        flags = HEARTBEAT_LOCKSTEP if lockstep else 0
        self.send(MsgType.HEARTBEAT, HeartbeatPayload(uptime, int(self.state), flags).pack(),
                  stamp_ns)

    def send_status(self) -> None:
        st = StatusPayload(int(self.state), self.encoding, self.decimation, self.f_center_hz,
                           self.decoder.frames_ok, self.counts["frames_out"],
                           self.decoder.crc_errors, self.decoder.dropped, self.link.reconnects)
        self.send(MsgType.STATUS, st.pack())

    def send_error(self, code: ErrorCode, ref_seq: int, text: str) -> None:
        self.send(MsgType.ERROR, ErrorPayload(int(code), ref_seq, text).pack())

    # ---- receiving -------------------------------------------------------------------------

    def _on_connect(self) -> None:
        self.decoder.reset()
        # a leading delimiter ends any partial frame the head may hold from before
        self.link.send(b"\x00")
        self.send_status()

    def _on_bytes(self, data: bytes) -> None:
        for frame in self.decoder.feed(data):
            try:
                self._handle(frame)
            except ValueError as exc:
                # CRC-valid but unparsable: a head speaking another revision. Tell it.
                self.counts["bad_payloads"] += 1
                unsupported = frame.msg_type == MsgType.PING and len(frame.payload) == PING.size
                code = ErrorCode.UNSUPPORTED_ENCODING if unsupported else ErrorCode.BAD_PAYLOAD
                self.send_error(code, frame.seq, str(exc))
                log.debug("%s: bad %s payload: %s", self.name, frame.msg_type, exc)
        with self._rx_cv:
            self._rx_cv.notify_all()

    def wait_for(self, predicate: Callable[[SonarHeadHost], bool], timeout: float) -> bool:
        """Block until ``predicate(self)`` holds, re-checked after each batch of received bytes."""
        with self._rx_cv:
            return self._rx_cv.wait_for(lambda: predicate(self), timeout)

    def _handle(self, frame: Frame) -> None:
        t = frame.msg_type
        if t == MsgType.PING:
            ping = PingPayload.unpack(frame.payload)
            self._ping_encoding[ping.ping_seq] = ping.encoding
            while len(self._ping_encoding) > 256:
                self._ping_encoding.popitem(last=False)
            self.counts["pings_in"] += 1
            if self._on_ping is not None:
                self._on_ping(ping, frame)
        elif t == MsgType.CONFIG:
            cfg = ConfigPayload.unpack(frame.payload)
            problems = cfg.problems(self.echo_fs_hz)
            if problems:
                self.counts["configs_refused"] += 1
                text = "CONFIG refused, previous kept: " + "; ".join(problems)
                self.send_error(ErrorCode.BAD_CONFIG, frame.seq, text[:MAX_ERROR_TEXT])
                log.warning("%s: %s", self.name, text)
                return
            changed = cfg != self.head_config
            self.head_config = cfg
            self.counts["configs_in"] += 1
            if changed:
                if self.follow_head_config:
                    self.encoding = cfg.encoding
                    if cfg.f_center_hz:
                        self.f_center_hz = cfg.f_center_hz
                    if cfg.decimation:
                        self.decimation = cfg.decimation
                if self._on_config is not None:
                    self._on_config(cfg)
        elif t == MsgType.STATUS:
            self.head_status = StatusPayload.unpack(frame.payload)
            self.counts["status_in"] += 1
        elif t == MsgType.HEARTBEAT:
            HeartbeatPayload.unpack(frame.payload)
            self.last_head_heartbeat = time.monotonic()
            self.counts["heartbeats_in"] += 1
        elif t == MsgType.ERROR:
            err = ErrorPayload.unpack(frame.payload)
            self.head_errors.append(err)
            self.counts["errors_in"] += 1
            log.debug("%s: head reports error %d (seq %d): %s", self.name, err.code,
                      err.ref_seq, err.text)
        else:
            self.counts["unexpected_in"] += 1
