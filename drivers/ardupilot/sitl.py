"""The ArduPilot SITL node: firmware in the loop over SITL's JSON physics interface.

``ArduPilotSitl(name, *, bus, instances, host="127.0.0.1", channels=None, reply_timeout_s=1.0)``
is a launchable node (its own process in a launch). For each entry of ``instances``
(``{vehicle_id, instance=None, port=None}``) it binds UDP port 9002 + 10·instance, as SITL's
``-I`` sets it (``port`` overrides; 0: any free port), and serves one SITL. The first
instance defaults to the run's domain number (``--domain``/``ECHOLOOP_DOMAIN``: two runs never
collide; :mod:`hil_bridge.bus.domain`), further ones must be given; a private domain (the pytest
fixture) binds a free port.

- every servo packet (:mod:`drivers.ardupilot.json_frames`) is checked: a short packet or a
  wrong magic is dropped and counted (``packets_bad``), never answered;
- its frame counter is followed: the same count again is SITL re-sending (``frames_repeated``:
  the last reply is sent again, nothing is flown), a gap is counted (``frames_lost``), a count
  that goes back is a restarted SITL (``sitl_restarts``, logged);
- the PWM become control surfaces (``channels``: ArduPlane's 1 aileron, 2 elevator,
  3 throttle, 4 rudder by default) published on ``/glider/<id>/surfaces`` as the answer to the
  state step last sent to SITL, so a ``lockstep`` server (with the vehicle in its
  ``autopilots``) flies exactly one tick per frame;
- then the node answers with exactly one JSON line of the next ``/glider/<id>/fdm`` state (a
  newer tick), stamped with that tick's sim time: SITL's clock is the server's; with
  ``sensors: {noise: true}`` its IMU is read by echoloop's sensor model (off by default: SITL
  adds its own noise). The answer
  leaves from the bus callback that receives the state (no thread hand-off), or at once when
  the state is already there. A server that does not tick within ``reply_timeout_s`` gets the
  newest state sent again (``replies_stale``: SITL does not advance on it); a state with a
  non-finite value is never sent (``states_nonfinite``).

``added_latency_us``: the node's own time per frame, from a servo packet's arrival to its
surfaces being published plus from the next state's arrival to the reply being sent.
"""

from __future__ import annotations

import functools
import logging
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal

from drivers.ardupilot.firmware import FirmwareProcess, FirmwareSpec, resolve_binary
from drivers.ardupilot.json_frames import (
    ChannelMap,
    FrameError,
    fdm_line,
    parse_servo_packet,
    surfaces_from_pwm,
)
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import fdm_truth
from sim_core.config import ConfigError, from_dict
from sim_core.sensors import SensorSpec, SensorSuite

__all__ = ["ArduPilotSitl", "SitlInstance", "SitlParams"]

log = logging.getLogger(__name__)

#: SITL's JSON port for instance 0; instance i uses BASE_PORT + 10·i
BASE_PORT = 9002


@dataclass(frozen=True, slots=True)
class SitlInstance:
    """One SITL: the scene's 6-DoF ``vehicle_id`` it flies, its ``instance`` number (``-I``;
    None: the domain's), the UDP ``port`` to serve (default 9002 + 10·instance) and, when the
    node starts the firmware itself (:class:`SitlParams` ``binary``), how
    (:class:`~drivers.ardupilot.firmware.FirmwareSpec`)."""

    vehicle_id: int
    instance: int | None = None
    port: int | None = None
    firmware: FirmwareSpec = field(default_factory=FirmwareSpec)

    def __post_init__(self) -> None:
        if self.vehicle_id < 0:
            raise ValueError(f"vehicle_id: expected >= 0, got {self.vehicle_id}")
        if self.instance is not None and not 0 <= self.instance < 100:
            raise ValueError(f"instance: expected 0 <= instance < 100, got {self.instance}")
        if self.port is not None and not 0 <= self.port <= 65535:
            raise ValueError(f"port: expected 0..65535 (0: any free port), got {self.port}")


@dataclass(frozen=True, slots=True)
class SitlParams:
    """Validated parameters of :class:`ArduPilotSitl`; ``sensors``: the IMU's model
    (:class:`sim_core.sensors.SensorSpec`), its noise seeded by ``seed`` and the vehicle id.
    Noise is off by default (SITL adds its own, ``SIM_ACC*_RND``, ``SIM_GYR*_RND``): the
    model then reads the truth exactly, and the node sends the state's own rates and specific
    force without sampling it (off the frame's path). ``surfaces``: ``pwm`` flies SITL's servo
    PWM; ``hold`` answers each frame's step and changes no surface, for a firmware that drives
    its servos by another wire (DroneCAN: ``drivers.dronecan``). ``binary``: an ArduPilot SITL
    executable the node runs for each instance, started once its port is bound and stopped
    before it closes (:mod:`drivers.ardupilot.firmware`; empty: SITL is started by someone
    else), in ``firmware_dir``/sitlN, kept (empty: the domain's directory, removed)."""

    instances: tuple[SitlInstance, ...]
    host: str = "127.0.0.1"
    channels: ChannelMap = field(default_factory=ChannelMap)
    reply_timeout_s: float = 1.0
    sensors: SensorSpec = field(default_factory=lambda: SensorSpec(noise=False))
    seed: int = 0
    surfaces: Literal["pwm", "hold"] = "pwm"
    binary: str = ""
    firmware_dir: str = ""

    def __post_init__(self) -> None:
        if not self.instances:
            raise ValueError("instances: expected at least one {vehicle_id, instance, port}")
        ids = [i.vehicle_id for i in self.instances]
        if len(set(ids)) != len(ids):
            raise ValueError(f"instances: a vehicle flown by two SITLs: {ids}")
        if not 0 < self.reply_timeout_s <= 60:
            raise ValueError(f"reply_timeout_s: expected 0 < s <= 60, got {self.reply_timeout_s}")


_COUNTERS = ("frames", "replies", "frames_repeated", "frames_lost", "sitl_restarts",
             "packets_bad", "replies_stale", "states_nonfinite", "surfaces_published")


@dataclass(frozen=True, slots=True)
class _Pending:
    """A frame waiting for its state: where to answer, the step its surfaces answered, when it
    arrived and when its surfaces were published (monotonic ns)."""

    addr: Any
    answered: int
    t_in: int
    t_pub: int


class _Link:
    """One SITL's socket and the state of its conversation."""

    def __init__(self, spec: SitlInstance, instance: int | None, host: str,
                 imu: SensorSuite | None) -> None:
        self.spec = spec
        self.imu = imu
        self.instance = instance
        port = spec.port if spec.port is not None else (
            0 if instance is None else BASE_PORT + 10 * instance)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise OSError(exc.errno, f"SITL instance {instance} (vehicle {spec.vehicle_id}): "
                          f"cannot bind UDP {host}:{port} ({exc.strerror}); another run may "
                          "serve that instance: give this one another 'instance' (and SITL the "
                          "same -I), a 'port', or run in another --domain") from exc
        self.sock.settimeout(0.1)
        self.port = int(self.sock.getsockname()[1])
        self.cond = threading.Condition()
        self.state: Any = None  # newest FdmState
        self.readings: Any = None  # its IMU (sim_core.sensors.SensorReadings)
        self.arrived_ns = 0  # when it arrived (monotonic)
        self.replied_step = -1
        self.last_reply: bytes | None = None
        self.last_count: int | None = None
        self.pending: _Pending | None = None
        self.c = dict.fromkeys(_COUNTERS, 0)
        self.added_us: deque[float] = deque(maxlen=100_000)


class ArduPilotSitl:
    """Launchable SITL JSON node (see the module docstring)."""

    #: a launch puts it in one process with a lockstep server (docs/launch.md, Composition)
    LOCKSTEP_PARTNER: ClassVar[bool] = True

    def __init__(self, name: str, *, bus: str, **params: Any) -> None:
        self.name = name
        self.bus = bus
        self.params = from_dict(SitlParams, params, path=f"{name}.params")
        first = current_domain().sitl_instance  # the run's: active while the launcher builds
        self._instances = [spec.instance if spec.instance is not None else (
            first if k == 0 else None) for k, spec in enumerate(self.params.instances)]
        missing = [s.vehicle_id for s, i in zip(self.params.instances, self._instances,
                                                 strict=True) if i is None and s.port is None]
        if missing and first is not None:
            raise ConfigError(f"{name}.params.instances: vehicle(s) {missing}: only the first "
                              "SITL takes the domain's instance; give the others 'instance' "
                              "or 'port'")
        self._firmware = self._firmware_for(name) if self.params.binary else {}
        self.faults = Faults(name)
        self._stop = threading.Event()
        self._links: list[_Link] = []
        self._threads: list[threading.Thread] = []
        self._node: Any = None
        self._pubs: dict[int, Any] = {}

    def _firmware_for(self, name: str) -> dict[int, FirmwareProcess]:
        """vehicle id -> the firmware the node runs for it (``binary``), checked now."""
        where = f"{name}.params"
        try:
            binary = resolve_binary(self.params.binary, f"{where}.binary")
            out = {}
            for k, (spec, inst) in enumerate(zip(self.params.instances, self._instances,
                                                 strict=True)):
                at = f"{where}.instances[{k}]"
                if inst is None:
                    raise ValueError(f"{at}.instance: the firmware the node starts needs an "
                                     "instance number (-I; its port is 9002 + 10·instance)")
                if spec.port is not None and spec.port != BASE_PORT + 10 * inst:
                    raise ValueError(f"{at}.port: {spec.port} is not instance {inst}'s JSON "
                                     f"port ({BASE_PORT + 10 * inst}), where its firmware sends")
                out[spec.vehicle_id] = FirmwareProcess(
                    binary, spec.firmware, instance=inst, host=self.params.host,
                    workdir=Path(self.params.firmware_dir) / f"sitl{inst}"
                    if self.params.firmware_dir else current_domain().path(f"sitl{inst}"),
                    keep=bool(self.params.firmware_dir), where=at)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        return out

    @property
    def ports(self) -> dict[int, int]:
        """vehicle id → the UDP port its SITL must send to (bound at :meth:`start`)."""
        return {ln.spec.vehicle_id: ln.port for ln in self._links}

    def start(self) -> None:
        from hil_bridge.bus.messages import FdmState, SurfaceCmd
        from hil_bridge.bus.node import Node
        from hil_bridge.bus.qos import COMMAND, SENSOR

        for spec, inst in zip(self.params.instances, self._instances, strict=True):
            imu = SensorSuite(self.params.sensors, 1, seed=self.params.seed,
                              key=(spec.vehicle_id,)) if self.params.sensors.noise else None
            try:
                self._links.append(_Link(spec, inst, self.params.host, imu))
            except OSError:
                for ln in self._links:
                    ln.sock.close()
                raise
        self._node = Node(self.name, bus=self.bus, faults=self.faults)
        for ln in self._links:
            vid = ln.spec.vehicle_id
            self._pubs[vid] = self._node.create_publisher(
                # flying SITL's PWM it is the vehicle's one source of surfaces (exclusive:
                # hil_bridge.bus.intra); holding, the surfaces come by another wire
                SurfaceCmd, f"/glider/{vid}/surfaces", qos=COMMAND,
                exclusive=self.params.surfaces == "pwm")
            self._node.create_subscription(
                FdmState, f"/glider/{vid}/fdm", self._on_state_for(ln), qos=SENSOR,
                priority=True, inline=True)
        self._node.start()
        for ln in self._links:
            t = threading.Thread(target=self.faults.guarded(f"SITL of vehicle {ln.spec.vehicle_id}",
                                                            functools.partial(self._serve, ln)),
                                 name=f"{self.name}-sitl{ln.spec.vehicle_id}", daemon=True)
            self._threads.append(t)
            t.start()
        log.info("%s: serving SITL JSON on %s", self.name,
                 ", ".join(f"{self.params.host}:{p} (vehicle {v})" for v, p in self.ports.items()))
        for vid, fw in self._firmware.items():
            fw.start()
            log.info("%s: vehicle %d's firmware runs in %s (pid %s): %s", self.name, vid,
                     fw.workdir, fw.pid, " ".join(fw.command))

    def stop(self) -> None:
        for fw in self._firmware.values():  # before its port closes: it stops as it flies
            fw.stop()
        self._stop.set()
        for ln in self._links:
            with ln.cond:
                ln.cond.notify_all()
        for t in self._threads:
            t.join()
        self._threads = []
        for ln in self._links:
            ln.sock.close()
        if self._node is not None:
            self._node.stop()
            self._node = None

    def stats(self) -> dict[str, Any]:
        from hil_bridge.bus.stats import percentiles

        out: dict[str, Any] = dict.fromkeys(_COUNTERS, 0)
        lat: list[float] = []
        per: dict[str, Any] = {}
        for ln in self._links:
            with ln.cond:
                c = dict(ln.c)
                lat.extend(ln.added_us)
            for k, v in c.items():
                out[k] += v
            per[str(ln.spec.vehicle_id)] = {"instance": ln.instance, "port": ln.port, **c}
            fw = self._firmware.get(ln.spec.vehicle_id)
            if fw is not None:
                per[str(ln.spec.vehicle_id)]["firmware"] = {
                    "pid": fw.pid, "workdir": str(fw.workdir), "command": fw.command}
        out["added_latency_us"] = percentiles(lat)
        out["vehicles"] = per
        return out

    def failure(self, *, final: bool = False) -> str | None:
        """Why the node failed (a SITL thread or a bus callback raised, a firmware it runs
        exited by itself), or None."""
        gone = next((why for fw in self._firmware.values() if (why := fw.failure())), None)
        return gone or self.faults.failure(final=final)

    # ------------------------------------------------------------------ bus thread

    def _on_state_for(self, ln: _Link) -> Any:
        def on_state(msg: Any) -> None:
            now = time.monotonic_ns()
            line = None
            with ln.cond:
                if ln.state is not None and msg.step <= ln.state.step:
                    return  # a tick sent again while the server waits
            imu = None if ln.imu is None else ln.imu.sample(int(msg.stamp_ns), fdm_truth([msg]))
            with ln.cond:
                ln.state, ln.readings, ln.arrived_ns = msg, imu, now
                pending = ln.pending
            base = None
            if pending is not None:  # SITL waits for this state: answer from here
                line = fdm_line(msg, imu)
                with ln.cond:
                    if ln.pending is pending:
                        base = self._answered(ln, line, msg, now, pending, stale=False)
                    else:
                        line = None
            with ln.cond:
                ln.cond.notify_all()
            if line is not None and pending is not None:
                ln.sock.sendto(line, pending.addr)
                if base is not None:
                    ln.added_us.append((base + time.monotonic_ns()) / 1e3)

        return on_state

    # ------------------------------------------------------------------ one SITL

    def _serve(self, ln: _Link) -> None:
        from hil_bridge.bus.messages import SurfaceCmd

        vid = ln.spec.vehicle_id
        pub = self._pubs[vid]
        chans = self.params.channels
        hold = self.params.surfaces == "hold"
        while not self._stop.is_set():
            try:
                data, addr = ln.sock.recvfrom(4096)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                raise
            t_in = time.monotonic_ns()
            try:
                pkt = parse_servo_packet(data)
            except FrameError as exc:
                with ln.cond:
                    ln.c["packets_bad"] += 1
                    first = ln.c["packets_bad"] == 1
                if first:
                    log.warning("%s: SITL %s: dropped a datagram from %s:%s: %s (counted in "
                                "packets_bad)", self.name, ln.instance, *addr[:2], exc)
                continue
            with ln.cond:
                ln.c["frames"] += 1
                last = ln.last_count
                ln.last_count = pkt.frame_count
                repeat = last is not None and pkt.frame_count == last
                if repeat:
                    ln.c["frames_repeated"] += 1
                elif last is not None and pkt.frame_count < last:
                    ln.c["sitl_restarts"] += 1
                    log.warning("%s: SITL %s restarted (frame %d after %d)", self.name,
                                ln.instance, pkt.frame_count, last)
                elif last is not None:
                    ln.c["frames_lost"] += pkt.frame_count - last - 1
                answered = ln.replied_step
                reply = ln.last_reply
                stamp = 0 if ln.state is None else ln.state.stamp_ns
            if repeat and reply is not None:
                ln.sock.sendto(reply, addr)
                with ln.cond:
                    ln.c["replies"] += 1
                continue
            t_pub = t_in
            if answered >= 0:
                a, e, t, r = surfaces_from_pwm(pkt.pwm, chans)
                pub.publish(SurfaceCmd(stamp_ns=stamp, aileron=a, elevator=e,
                                       throttle=t, rudder=r, glider_id=vid, step=answered,
                                       hold=hold))
                t_pub = time.monotonic_ns()
                with ln.cond:
                    ln.c["surfaces_published"] += 1
            self._await_state(ln, _Pending(addr, answered, t_in, t_pub))

    def _await_state(self, ln: _Link, pending: _Pending) -> None:
        """Answer one frame with the first state newer than ``pending.answered``: at once if it
        is here, else from the bus callback when it comes (:meth:`_on_state_for`), else, after
        ``reply_timeout_s``, with the newest state (stale)."""
        deadline = time.monotonic() + self.params.reply_timeout_s
        line = None
        base = None
        with ln.cond:
            state = ln.state
            if state is not None and state.step > pending.answered:
                line = fdm_line(state, ln.readings)
                base = self._answered(ln, line, state, ln.arrived_ns, pending, stale=False)
            else:
                ln.pending = pending
                while ln.pending is pending and not self._stop.is_set():
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    ln.cond.wait(left)
                if ln.pending is pending:  # no newer state in time
                    ln.pending = None
                    state = ln.state
                    if state is not None and not self._stop.is_set():
                        line = fdm_line(state, ln.readings)
                        self._answered(ln, line, state, ln.arrived_ns, pending, stale=True)
        if line is not None:
            ln.sock.sendto(line, pending.addr)
            if base is not None:
                ln.added_us.append((base + time.monotonic_ns()) / 1e3)

    @staticmethod
    def _answered(ln: _Link, line: bytes | None, state: Any, arrived: int, pending: _Pending,
                  *, stale: bool) -> int | None:
        """Book an answer (under ``ln.cond``) before it is sent, so the next frame answers
        this state's step. Returns the node's own time so far minus the state's arrival (ns;
        the send time completes it), or None for no answer or a stale one."""
        ln.pending = None
        if line is None:
            ln.c["states_nonfinite"] += 1
            return None
        ln.c["replies"] += 1
        ln.c["replies_stale"] += int(stale)
        ln.replied_step = max(ln.replied_step, int(state.step))
        ln.last_reply = line
        if stale:
            return None
        return pending.t_pub - pending.t_in - max(arrived, pending.t_pub)
