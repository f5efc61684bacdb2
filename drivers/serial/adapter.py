"""``SonarHeadAdapter``: bus node for a sonar head on a serial port (launch name ``sonar_head``).

Data flow (spec §1 topics, §2 frames)::

    head --PING--> adapter --/sonar/<id>/ping (SonarPing)--> simulator
    head <--ECHO chunks-- adapter <--/sonar/<id>/echo (SonarEcho)-- simulator

Echoes go out in the encoding the PING asked for (the ``encoding`` parameter for echoes of
pings the adapter never saw); IQ16 uses the centre frequency and decimation of the head's
CONFIG (``follow_head_config``) or the parameters. At construction the link budget of the
configured baud rate, ping rate and encoding is checked: ``budget: warn`` logs a warning,
``budget: refuse`` raises ``ValueError``; a CONFIG from the head is re-checked (warning + an
ERROR frame to the head + STATUS state OVER_BUDGET). Heartbeat and STATUS go to the head every
``heartbeat_period_s`` wall seconds. The port is re-opened with back-off when it disappears.

**Lockstep** (``/clock`` says ``lockstep``; docs/serial.md): every ``/clock`` goes to the head
as a HEARTBEAT flagged ``LOCKSTEP`` whose frame stamp is the sim time; a head that supports it
fires its pings on that time and stamps them with it. The ping is published with that stamp
and ``next_ns`` = stamp + the head's ping period (its CONFIG rate, else ``ping_rate_hz``), so
the server answers it at the pose of that sim time and waits for the next one. A ping stamped
later than the sim time sent to the head was fired on the head's own clock (before it followed
the host): it is published without ``next_ns`` (counted in ``pings_own_clock``), and the server
does not answer such pings of a lockstep head.
Otherwise a ping is stamped with the sim time of the latest ``/clock`` the adapter saw (its
arrival, in sim time), which the server takes as its emission.

The port dropping is a fault the adapter recovers from (its link re-opens it); one that never
comes back by the end of the run, a callback of the link or the heartbeat thread that raises,
fail the node (``failure()``, :mod:`hil_bridge.bus.faults`).

``stats()`` adds to the node's bus counters: ``frames_in``, ``frames_out``, ``crc_errors``,
``frames_dropped`` (any decode failure), ``echoes_out``, ``echoes_dropped``, ``reconnects``,
``pings_in``, ``link_state`` (0 ok, 1 degraded = frames dropped in the last heartbeat period,
2 over budget), ``link_utilisation`` and the decoder/link detail; all of them reach
``/diagnostics``. Parameters: :class:`SonarHeadParams` (docs/serial.md).
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import Any, Literal

from drivers.serial.framing import Frame
from drivers.serial.host import LinkBudget, SonarHeadHost, link_budget
from drivers.serial.protocol import (
    ConfigPayload,
    Encoding,
    ErrorCode,
    LinkState,
    PingPayload,
    ping_period_ns,
)
from hil_bridge.bus.clock import SimClock
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.messages import Clock, SonarEcho, SonarPing
from hil_bridge.bus.node import Node
from sim_core.config import from_dict

__all__ = ["SonarHeadAdapter", "SonarHeadParams"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class SonarHeadParams:
    """Launch parameters of ``sonar_head`` (see docs/serial.md for how to choose them).

    ``port``: device path, pty path/symlink or URL (``loop://``, ``socket://h:p``,
    ``sonarsim://?...``); default the domain's link ``sonar<sonar_id>``, where
    ``MockSonarHead(pty=True)`` and ``echoloop mock sonar-head --pty`` put their pty
    (:mod:`hil_bridge.bus.domain`). ``capture``: path prefix for the raw byte capture (None: off).
    ``ping_rate_hz``/``echo_samples``/``channels``: what the link budget assumes (samples per
    channel at the echo rate, before IQ decimation).
    """

    port: str | None = None
    baudrate: int = 921600
    capture: str | None = None
    sonar_id: int = 0
    encoding: int | str = "int16"
    ping_rate_hz: float = 10.0
    echo_samples: int = 24000
    channels: int = 1
    f_center_hz: int = 70000
    decimation: int = 20
    budget: Literal["warn", "refuse"] = "warn"
    follow_head_config: bool = True
    heartbeat_period_s: float = 1.0
    backoff_initial_s: float = 0.05
    backoff_max_s: float = 2.0
    tx_queue_bytes: int = 256 * 1024
    echo_fs_hz: int = 400_000
    diagnostics_period_s: float = 1.0

    def __post_init__(self) -> None:
        if self.baudrate <= 0:
            raise ValueError(f"baudrate {self.baudrate!r} must be > 0")
        if not 0 <= self.sonar_id <= 255:
            raise ValueError(f"sonar_id {self.sonar_id!r} must be in 0..255")
        Encoding.parse(self.encoding)
        if self.ping_rate_hz <= 0 or self.echo_samples < 0 or not 1 <= self.channels <= 255:
            raise ValueError(
                f"ping_rate_hz {self.ping_rate_hz!r} must be > 0, echo_samples "
                f"{self.echo_samples!r} >= 0, channels {self.channels!r} in 1..255")
        if self.heartbeat_period_s <= 0:
            raise ValueError(f"heartbeat_period_s {self.heartbeat_period_s!r} must be > 0")
        if self.tx_queue_bytes <= 0:
            raise ValueError(f"tx_queue_bytes {self.tx_queue_bytes!r} must be > 0")


class SonarHeadAdapter(Node):
    """Serial sonar head <-> bus (module docstring). ``Cls(name, *, bus, **params)``;
    ``overwrite=True`` lets ``capture`` replace existing capture files."""

    def __init__(
        self,
        name: str = "sonar_head",
        *,
        bus: str | None = None,
        clock: SimClock | None = None,
        overwrite: bool = False,
        **params: Any,
    ) -> None:
        self.params = p = from_dict(SonarHeadParams, params)
        self.budget = link_budget(
            baudrate=p.baudrate, ping_rate_hz=p.ping_rate_hz, echo_samples=p.echo_samples,
            channels=p.channels, encoding=Encoding.parse(p.encoding), decimation=p.decimation,
            heartbeat_hz=1.0 / p.heartbeat_period_s)
        self._check_budget(self.budget, refuse=p.budget == "refuse", source="parameters")
        super().__init__(name, bus=bus, clock=clock, diagnostics_period_s=p.diagnostics_period_s)
        self.sonar_id = p.sonar_id
        self.port = p.port if p.port is not None else str(
            current_domain().path(f"sonar{p.sonar_id}"))
        self.host = SonarHeadHost(
            self.port, baudrate=p.baudrate, encoding=p.encoding, f_center_hz=p.f_center_hz,
            decimation=p.decimation, follow_head_config=p.follow_head_config,
            capture=p.capture, overwrite=overwrite, on_ping=self._on_ping,
            on_config=self._on_config,
            backoff_initial_s=p.backoff_initial_s, backoff_max_s=p.backoff_max_s,
            tx_queue_bytes=p.tx_queue_bytes, echo_fs_hz=p.echo_fs_hz, name=name,
            faults=self.faults)
        if not self.budget.fits:
            self.host.state = LinkState.OVER_BUDGET
        self._ping_pub = self.create_publisher(SonarPing, f"/sonar/{p.sonar_id}/ping")
        self.create_subscription(SonarEcho, f"/sonar/{p.sonar_id}/echo", self._on_echo)
        self.create_subscription(Clock, "/clock", self._on_clock)
        self._lockstep = False
        self._sim_ns = 0
        self._bus_ns = 0  # the latest /clock, lockstep or not: stamps pings on arrival
        self._beat_stop = threading.Event()
        self._beat_thread: threading.Thread | None = None

    # ---- link budget -----------------------------------------------------------------------

    def _check_budget(self, b: LinkBudget, *, refuse: bool, source: str) -> None:
        if b.fits:
            log.info("sonar link budget OK (%s): %s", source, b.describe())
            return
        msg = f"sonar link over budget ({source}): {b.describe()}"
        if refuse:
            raise ValueError(msg + "; lower ping_rate_hz, use encoding iq16 or raise baudrate")
        log.warning(msg)

    def _on_config(self, cfg: ConfigPayload) -> None:
        p = self.params
        b = link_budget(
            baudrate=cfg.baudrate or p.baudrate, ping_rate_hz=(cfg.ping_rate_mhz / 1000.0)
            or p.ping_rate_hz, echo_samples=p.echo_samples, channels=cfg.channels or p.channels,
            encoding=cfg.encoding, decimation=self.host.decimation,
            heartbeat_hz=1.0 / p.heartbeat_period_s)
        self.budget = b
        self._check_budget(b, refuse=False, source="head CONFIG")
        if b.fits:
            if self.host.state == LinkState.OVER_BUDGET:
                self.host.state = LinkState.OK
        else:
            self.host.state = LinkState.OVER_BUDGET
            self.host.send_error(ErrorCode.OVER_BUDGET, 0, b.describe())

    # ---- data path -------------------------------------------------------------------------

    def _on_clock(self, msg: Clock) -> None:
        self._bus_ns = max(self._bus_ns, int(msg.stamp_ns))
        self._lockstep = bool(msg.lockstep)
        if self._lockstep:
            self._sim_ns = max(self._sim_ns, int(msg.stamp_ns))
            if self.host.link.connected:
                self.host.send_heartbeat(stamp_ns=self._sim_ns, lockstep=True)

    def _on_ping(self, ping: PingPayload, frame: Frame) -> None:
        stamp, next_ns = self._bus_ns, -1
        if self._lockstep and frame.stamp_ns > self._sim_ns:
            self.host.counts["pings_own_clock"] += 1  # fired before the head followed us
        elif self._lockstep:
            cfg = self.host.head_config
            mhz = cfg.ping_rate_mhz if cfg is not None and cfg.ping_rate_mhz else round(
                self.params.ping_rate_hz * 1000)
            stamp = int(frame.stamp_ns)
            next_ns = stamp + ping_period_ns(mhz)
        self._ping_pub.publish(SonarPing(
            stamp_ns=stamp, ping_seq=ping.ping_seq, az=ping.az, el=ping.el,
            beamwidth=ping.beamwidth, encoding=int(ping.encoding), sonar_id=self.sonar_id,
            next_ns=next_ns))

    def _on_echo(self, msg: SonarEcho) -> None:
        try:
            self.host.send_echo(msg.ping_seq, msg.samples, msg.fs, stamp_ns=msg.stamp_ns)
        except ValueError as exc:
            self.host.counts["echo_errors"] += 1
            self.host.send_error(ErrorCode.NO_ECHO, msg.ping_seq, str(exc))
            log.warning("%s: echo %d not sent: %s", self.name, msg.ping_seq, exc)

    # ---- lifecycle -------------------------------------------------------------------------

    def start(self) -> SonarHeadAdapter:
        super().start()
        self.host.start()
        if self._beat_thread is None:
            self._beat_thread = threading.Thread(
                target=self.faults.guarded("heartbeat loop", self._beat_loop),
                name=f"{self.name}-beat", daemon=True)
            self._beat_thread.start()
        return self

    def stop(self) -> None:
        self._beat_stop.set()
        if self._beat_thread is not None:
            self._beat_thread.join()
        self.host.stop()
        super().stop()

    def _beat_loop(self) -> None:
        period = self.params.heartbeat_period_s
        while not self._beat_stop.wait(period):
            self.host.update_state()
            if self.host.link.connected:
                self.host.send_heartbeat(stamp_ns=self._sim_ns, lockstep=self._lockstep)
                self.host.send_status()

    def stats(self) -> dict[str, Any]:
        out = super().stats()
        serial = self.host.stats()
        out.update({
            "frames_in": serial["frames_in"],
            "frames_out": serial["frames_out"],
            "crc_errors": serial["crc_errors"],
            "frames_dropped": serial["decoder_dropped"],
            "echoes_out": serial.get("echoes_out", 0),
            "echoes_dropped": serial.get("echoes_dropped", 0),
            "echo_errors": serial.get("echo_errors", 0),
            "pings_in": serial.get("pings_in", 0),
            "configs_refused": serial.get("configs_refused", 0),
            "reconnects": serial["reconnects"],
            "link_state": serial["state"],
            "link_connected": int(bool(serial["link_connected"])),
            "link_utilisation": round(self.budget.utilisation, 4),
        })
        out["serial"] = serial
        out["links"] = {"serial": self.host.link.report()}
        return out
