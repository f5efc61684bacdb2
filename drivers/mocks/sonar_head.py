"""A mock biomimetic sonar head: the device end of a serial link, speaking spec §2.

:class:`MockSonarHead` is a launchable (``Cls(name, *, bus, **params)``, ``start``, ``stop``,
``stats``) and runs alone via ``echoloop mock sonar-head``. It

1. owns a device port: a new pty (``pty=True``) symlinked to ``link`` (default the domain's
   ``sonar<sonar_id>``, where ``SonarHeadAdapter`` looks by default; :mod:`hil_bridge.bus.domain`),
   an existing serial URL (``port=...``, e.g. one end of a null-modem cable or ``socket://``),
   or an in-process pipe (the ``sonarsim://`` pyserial URL handler);
2. sends CONFIG and HEARTBEAT once a second (CONFIG also as soon as a host (re)appears, i.e.
   its first frame after a second of silence) and a PING at ``rate_hz`` with a fixed beamwidth or
   one drawn uniformly from [30°, 65°] per ping (seed 000's scenario II) from its seeded rng —
   on its own clock, or, once the host sends HEARTBEATs flagged ``LOCKSTEP``, on the host's sim
   time (their frame stamps). Entering lockstep restarts the ping stream (``ping_seq`` 0, the
   beamwidth rng re-seeded, pings in flight forgotten), so it does not depend on how many pings
   the head fired on its own clock before; then ping ``n`` goes at ``n`` ping periods of sim
   time, its PING frame stamped with that time, and ping ``n + 1`` only once the echo of ping
   ``n`` is complete, as the echo of a real ping returns before the next one. A ping whose echo
   has not come within ``echo_timeout_s`` of wall time (counted in ``echo_timeouts``) is fired
   again, the same frame content (seq, stamp, beam; ``pings_refired``): the host's loop waits
   for that ping, so one lost on the way (a corrupt frame, a lost message) must not hold it up;
3. throttles both directions to ``baudrate`` (10 bits per byte, 8N1) — ptys and pipes move
   bytes instantly, a UART does not — so latencies are those of the real link;
4. decodes and reassembles ECHO chunks (CRC, order, completeness, encoding = the one the ping
   requested; an abandoned echo or an unparsable payload is reported to the host in an ERROR
   frame), estimates the range of the first return above a threshold and measures the
   latency from firing a ping to receiving the last chunk of its echo.

The ``bus`` argument is accepted for the launch contract only: a device speaks serial, never
the bus. Its counters are available through ``stats()`` (the launch run summary); an exception
that ends its receive or transmit thread is reported to its ``faults`` (``failure()``).

This module holds the device's protocol state machine; its parameters are
:class:`~drivers.mocks.sonar_head_config.SonarHeadConfig`, its port and UART pacing are in
:mod:`drivers.serial.device_port`; its range estimate is echoloop's one echo → range rule
(:mod:`sim_core.sensors.echo_range`).
"""

from __future__ import annotations

import collections
import math
import threading
import time
from typing import Any

import numpy as np

from drivers.mocks.sonar_head_config import BEAMWIDTH_RANGE_DEG, SonarHeadConfig
from drivers.serial.device_port import DevicePort, SerialDevicePort, UartPacer
from drivers.serial.framing import FrameDecoder, MsgType, frame_bytes
from drivers.serial.protocol import (
    AssembledEcho,
    ConfigPayload,
    EchoAssembler,
    EchoChunk,
    Encoding,
    ErrorCode,
    ErrorPayload,
    HeartbeatPayload,
    PingPayload,
    StatusPayload,
    ping_period_ns,
)
from drivers.serial.ptyport import PtyPort
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.faults import Faults
from sim_core.config import from_dict
from sim_core.rng import make_rng
from sim_core.sensors.echo_range import RangeRule, echo_ranges

__all__ = ["MockSonarHead"]

_LATENCY_WINDOW = 4096


class MockSonarHead:
    """The mock device (see module docstring). Construct, ``start()``, ``stop()``."""

    def __init__(
        self,
        name: str = "sonar_head_mock",
        *,
        bus: str = "",
        port: str | None = None,
        pty: bool = False,
        link: str | None = None,
        device: DevicePort | None = None,
        sonar_id: int = 0,
        **params: Any,
    ) -> None:
        self.name = name
        self.bus = bus
        self.cfg = from_dict(SonarHeadConfig, params)
        sources = sum([port is not None, bool(pty) or link is not None, device is not None])
        if sources != 1:
            raise ValueError(
                f"{name}: give exactly one of port=URL, pty=true (optionally link=PATH) or a "
                f"device; got port={port!r}, pty={pty!r}, link={link!r}"
            )
        self._port_url = port
        self._use_pty = bool(pty) or link is not None
        if self._use_pty and link is None:
            link = str(current_domain().path(f"sonar{int(sonar_id)}"))
        self._pty_link = link
        self._device = device
        self.pty: PtyPort | None = None
        self.encoding = Encoding.parse(self.cfg.encoding)
        self._rng = make_rng(self.cfg.seed)
        self._stop = threading.Event()
        self._tx_wake = threading.Event()
        self._errors: collections.deque[ErrorPayload] = collections.deque(maxlen=64)
        self._config_due = True
        self._host_seen_at: float | None = None
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._decoder = FrameDecoder()
        self._assembler = EchoAssembler()
        self._tx_uart = UartPacer(self.cfg.baudrate, self.cfg.throttle)
        self._rx_uart = UartPacer(self.cfg.baudrate, self.cfg.throttle)
        self._pending: dict[int, tuple[float, Encoding]] = {}
        #: ping_seqs that timed out lately (an echo of one arriving afterwards is late)
        self._expired: collections.deque[int] = collections.deque(maxlen=256)
        self._latencies: collections.deque[float] = collections.deque(maxlen=_LATENCY_WINDOW)
        self.ranges: collections.deque[float | None] = collections.deque(maxlen=_LATENCY_WINDOW)
        absolute = self.cfg.threshold
        self._rule = RangeRule(
            threshold_db=-400.0 if absolute is None else 20.0 * math.log10(absolute),
            relative_db=20.0 * math.log10(self.cfg.threshold_rel),
            sound_speed=self.cfg.sound_speed, min_range_m=0.0)
        self._seq = 0
        self._ping_seq = 0
        self._t0 = time.monotonic()
        #: lockstep: the host's sim time, the next ping's sim time, and the wall deadline of
        #: the echo the next ping waits for (None: none pending)
        self._lockstep = False
        self._lockstep_asked = False
        self._host_ns = -1
        self._next_ping_ns: int | None = None
        self._period_ns = ping_period_ns(round(self.cfg.rate_hz * 1000))
        self._echo_wait_until: float | None = None
        #: the last sim-time ping (seq, payload, stamp), fired again if its echo times out
        self._last_ping: tuple[int, bytes, int] | None = None
        self._echo_done = threading.Condition(self._lock)
        self.last_status: StatusPayload | None = None
        self.last_error: ErrorPayload | None = None
        self.last_echo: AssembledEcho | None = None
        self._counts = collections.Counter[str]()
        self._started = False
        self._stopped = False
        #: what ended one of its threads (:mod:`hil_bridge.bus.faults`)
        self.faults = Faults(name)

    # ---- lifecycle -------------------------------------------------------------------------

    @property
    def path(self) -> str:
        """What the host opens: the symlink if any, else the pty slave path, else the URL."""
        if self.pty is not None:
            return str(self.pty.link) if self.pty.link is not None else self.pty.path
        return self._port_url or ""

    def start(self) -> None:
        if self._started:
            return
        self._started = True
        if self._device is None:
            if self._use_pty:
                self.pty = PtyPort(self._pty_link)
                self._device = self.pty
            else:
                self._device = SerialDevicePort(str(self._port_url), self.cfg.baudrate)
        self._t0 = time.monotonic()
        for target, suffix in ((self._rx_loop, "rx"), (self._tx_loop, "tx")):
            t = threading.Thread(target=self.faults.guarded(f"{suffix} loop", target),
                                 name=f"{self.name}-{suffix}", daemon=True)
            self._threads.append(t)
            t.start()

    def stop(self) -> None:
        if self._stopped:
            return
        self._stopped = True
        self._stop.set()
        self._tx_wake.set()
        if self._device is not None:
            self._device.wake()
        for t in self._threads:
            t.join(timeout=5.0)
        if self._device is not None:
            self._device.close()

    close = stop

    def __enter__(self) -> MockSonarHead:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def failure(self, *, final: bool = False) -> str | None:
        """Why the mock failed (one of its threads ended by an exception), or None."""
        return self.faults.failure(final=final)

    def wait_echoes(self, n: int, timeout: float) -> bool:
        """Block until ``n`` pings had their echo complete in time (True) or ``timeout`` s
        pass (False)."""
        with self._echo_done:
            return self._echo_done.wait_for(lambda: self._counts["echoes_complete"] >= n,
                                            timeout)

    def stats(self) -> dict[str, Any]:
        """Counters. Every ping sent, and every one fired again, has exactly one outcome, so
        ``pings_sent`` + ``pings_refired`` = ``echoes_complete`` (its echo arrived whole in
        time) + ``echoes_incomplete`` (its echo was abandoned part way) + ``echo_timeouts``
        (nothing whole within ``echo_timeout_s``) + ``pings_in_flight``. ``echoes_late``
        (whole, after the timeout), ``echoes_unsolicited`` and the reassembler's raw
        ``assembled_*`` counts are extra."""
        with self._lock:
            lat = np.asarray(self._latencies, dtype=np.float64)
            last_range = self.ranges[-1] if self.ranges else None
            out: dict[str, Any] = dict.fromkeys(
                ("pings_sent", "pings_refired", "echoes_complete", "echoes_incomplete",
                 "echo_timeouts", "echoes_late"), 0)
            out.update(self._counts)
            out["pings_in_flight"] = len(self._pending)
            out["assembled_complete"] = self._assembler.complete
            out["assembled_incomplete"] = self._assembler.incomplete
            out["chunk_duplicates"] = self._assembler.duplicates
            out.update({f"decoder_{k}": v for k, v in self._decoder.stats().items()})
        out["crc_errors"] = self._decoder.crc_errors
        out["frames_dropped"] = self._decoder.dropped
        out["latency_p50_ms"] = float(np.percentile(lat, 50) * 1e3) if lat.size else None
        out["latency_p99_ms"] = float(np.percentile(lat, 99) * 1e3) if lat.size else None
        out["latency_max_ms"] = float(lat.max() * 1e3) if lat.size else None
        out["last_range_m"] = last_range
        out["port"] = self.path
        return out

    def _range(self, samples: np.ndarray, fs: float) -> float | None:
        """The range of the echo's first return over every ear (m), or None."""
        ranges = echo_ranges(samples, fs, self._rule).range_m
        return None if np.isnan(ranges).all() else float(np.nanmin(ranges))

    def latencies_s(self) -> np.ndarray:
        """Ping -> last-chunk latencies (s) of the most recent echoes (up to 4096)."""
        with self._lock:
            return np.asarray(self._latencies, dtype=np.float64)

    # ---- transmit side ---------------------------------------------------------------------

    def _send(self, msg_type: MsgType, payload: bytes, stamp_ns: int | None = None) -> None:
        device = self._device
        if device is None:
            raise ValueError(f"{self.name}: not started")
        stamp = time.monotonic_ns() if stamp_ns is None else stamp_ns
        data = frame_bytes(msg_type, self._seq, stamp, payload)
        self._seq = (self._seq + 1) & 0xFFFF
        done = self._tx_uart.done_at(len(data), time.monotonic())
        delay = done - time.monotonic()
        if delay > 0:
            self._stop.wait(delay)
        n = device.write(data, 0.05)  # a UART never blocks: bytes nobody takes are lost
        self._counts["bytes_tx"] += n
        self._counts["frames_tx"] += 1
        if n < len(data):
            self._counts["tx_lost_bytes"] += len(data) - n

    def _beamwidth_rad(self) -> float:
        if self.cfg.beamwidth == "random":
            lo, hi = BEAMWIDTH_RANGE_DEG
            return math.radians(float(self._rng.uniform(lo, hi)))
        return math.radians(float(self.cfg.beamwidth))

    def _uptime_ms(self) -> int:
        return int((time.monotonic() - self._t0) * 1e3)

    def _tx_loop(self) -> None:
        period = 1.0 / self.cfg.rate_hz
        config = ConfigPayload(self.encoding, self.cfg.channels,
                               round(self.cfg.rate_hz * 1000), self.cfg.baudrate,
                               self.cfg.f_center_hz, self.cfg.decimation)
        next_ping = time.monotonic()
        next_beat = next_ping
        while not self._stop.is_set():
            now = time.monotonic()
            if self._config_due:
                self._config_due = False
                self._send(MsgType.CONFIG, config.pack())
            while self._errors:
                self._send(MsgType.ERROR, self._errors.popleft().pack())
                self._counts["errors_tx"] += 1
            if now >= next_beat:
                self._send(MsgType.HEARTBEAT, HeartbeatPayload(self._uptime_ms()).pack())
                next_beat += 1.0
                self._config_due = True
                self._expire(now)
            wake_at = next_beat
            if self._lockstep_asked and not self._lockstep:
                self._enter_lockstep()
            if self._lockstep:
                wake_at = min(wake_at, self._lockstep_ping(now))
            else:
                if now >= next_ping:
                    self._ping(now)
                    next_ping += period
                    if next_ping < now:  # fell behind (tiny period or a stall): skip, no burst
                        self._counts["pings_skipped"] += 1
                        next_ping = now + period
                wake_at = min(wake_at, next_ping)
            self._tx_wake.wait(max(0.0, wake_at - time.monotonic()))
            self._tx_wake.clear()

    def _enter_lockstep(self) -> None:
        """Restart the ping stream on the host's sim time (transmit thread; module doc)."""
        with self._lock:
            self._lockstep = True
            self._ping_seq = 0
            self._rng = make_rng(self.cfg.seed)
            self._pending.clear()
            self._last_ping = None
            self._next_ping_ns = None
            self._echo_wait_until = None
            self._counts["lockstep_starts"] += 1

    def _lockstep_ping(self, now: float) -> float:
        """Fire the ping due at the host's sim time, if the last echo is in; return when to
        look again (wall, monotonic s) without a wake-up."""
        refire = None
        with self._lock:
            host_ns, due = self._host_ns, self._next_ping_ns
            waiting = self._echo_wait_until
            if waiting is not None and (not self._pending or now >= waiting):
                if self._pending:
                    self._counts["echo_timeouts"] += len(self._pending)
                    self._pending.clear()
                    refire = self._last_ping
                waiting = self._echo_wait_until = None
            if refire is not None:
                self._pending[refire[0]] = (now, self.encoding)
                self._counts["pings_refired"] += 1
                self._echo_wait_until = now + self.cfg.echo_timeout_s
        if refire is not None:
            self._send(MsgType.PING, refire[1], refire[2])
            return now
        if host_ns < 0:
            return now + 1.0
        if due is None:
            due = self._next_ping_ns = -(-host_ns // self._period_ns) * self._period_ns
        if waiting is not None:
            return waiting
        if host_ns >= due:
            self._ping(now, stamp_ns=due)
            with self._lock:
                self._next_ping_ns = due + self._period_ns
                self._echo_wait_until = now + self.cfg.echo_timeout_s
            return now
        return now + 1.0

    def _ping(self, t_fire: float, stamp_ns: int | None = None) -> None:
        seq = self._ping_seq
        self._ping_seq = (seq + 1) & 0xFFFF
        ping = PingPayload(seq, math.radians(self.cfg.az_deg), math.radians(self.cfg.el_deg),
                           self._beamwidth_rad(), self.encoding)
        payload = ping.pack()
        with self._lock:
            self._pending[seq] = (t_fire, self.encoding)
            self._counts["pings_sent"] += 1
            if stamp_ns is not None:
                self._last_ping = (seq, payload, stamp_ns)
        self._send(MsgType.PING, payload, stamp_ns)

    def _expire(self, now: float) -> None:
        with self._lock:
            old = [s for s, (t, _) in self._pending.items() if now - t > self.cfg.echo_timeout_s]
            for s in old:
                del self._pending[s]
                self._expired.append(s)
            self._counts["echo_timeouts"] += len(old)

    # ---- receive side ----------------------------------------------------------------------

    def _rx_loop(self) -> None:
        device = self._device
        if device is None:
            raise ValueError(f"{self.name}: not started")
        chunk = 1024
        while not self._stop.is_set():
            data = device.read(chunk, 0.05)
            if not data:
                continue
            done = self._rx_uart.done_at(len(data), time.monotonic())
            delay = done - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                return
            with self._lock:
                self._counts["bytes_rx"] += len(data)
                frames = self._decoder.feed(data)
            if frames:
                now = time.monotonic()
                if self._host_seen_at is None or now - self._host_seen_at > 1.0:
                    # a host (re)appeared: tell it our configuration now, not at the next beat
                    self._config_due = True
                    self._tx_wake.set()
                self._host_seen_at = now
            for f in frames:
                self._handle(f.msg_type, f.seq, f.payload, f.stamp_ns)

    def _report(self, err: ErrorPayload) -> None:
        """Queue an ERROR frame for the host (sent by the transmit thread)."""
        self._errors.append(err)
        self._tx_wake.set()

    def _on_host_time(self, stamp_ns: int) -> None:
        """A lockstep HEARTBEAT: the host's sim time is ``stamp_ns``; ping on it from now on."""
        with self._lock:
            self._lockstep_asked = True
            if stamp_ns > self._host_ns:
                self._host_ns = stamp_ns
        self._tx_wake.set()

    def _handle(self, msg_type: int, seq: int, payload: bytes, stamp_ns: int = 0) -> None:
        try:
            if msg_type == MsgType.ECHO:
                self._on_chunk(EchoChunk.unpack(payload))
            elif msg_type == MsgType.STATUS:
                self.last_status = StatusPayload.unpack(payload)
                self._counts["status_rx"] += 1
            elif msg_type == MsgType.HEARTBEAT:
                beat = HeartbeatPayload.unpack(payload)
                self._counts["heartbeats_rx"] += 1
                if beat.lockstep:
                    self._on_host_time(stamp_ns)
            elif msg_type == MsgType.ERROR:
                self.last_error = ErrorPayload.unpack(payload)
                self._counts["errors_rx"] += 1
            else:
                self._counts["unexpected_rx"] += 1
        except ValueError as exc:
            self._counts["bad_payloads"] += 1
            self._report(ErrorPayload(ErrorCode.BAD_PAYLOAD, seq, str(exc)))

    def _on_chunk(self, chunk: EchoChunk) -> None:
        now = time.monotonic()
        with self._echo_done:
            self._counts["chunks_rx"] += 1
            incomplete = self._assembler.incomplete
            echo = self._assembler.feed(chunk)
            if self._assembler.incomplete > incomplete:
                lost = self._assembler.last_incomplete_ping
                ref = chunk.ping_seq if lost is None else lost
                self._report(ErrorPayload(ErrorCode.ECHO_INCOMPLETE, ref,
                                          f"echo of ping {ref} incomplete"))
                if self._pending.pop(ref, None) is not None:
                    self._counts["echoes_incomplete"] += 1
            if echo is None:
                return
            sent = self._pending.pop(echo.ping_seq, None)
            if sent is None:
                late = echo.ping_seq in self._expired
                self._counts["echoes_late" if late else "echoes_unsolicited"] += 1
            else:
                self._counts["echoes_complete"] += 1
                self._latencies.append(now - sent[0])
                if sent[1] != echo.encoding:
                    self._counts["encoding_mismatch"] += 1
            self.ranges.append(self._range(echo.samples, echo.fs_hz))
            self.last_echo = echo
            self._echo_done.notify_all()
        self._tx_wake.set()  # a lockstep head may fire its next ping now

