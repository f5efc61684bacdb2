"""The ROS 2 bridge node: echoloop's bus on one side, a ROS 2 graph (rclpy, DDS) on the other.

``Ros2Bridge(name, *, bus, mapping=None, world_frame="map", ros_domain_id=None,
discovery=None, dds_transport="udp")`` is a launchable node (entry
``ros2_bridge.bridge:Ros2Bridge``, or ``echoloop ros2 bridge``). It reads the bus with raw
prefix subscriptions, so it bridges gliders and sonars it was not told about: a ROS 2 publisher
is made for each bus topic the first time that topic is seen, and a command subscription for
each glider the first time one of its topics is seen.

- **Two receive paths.** ``/clock`` and ``/glider/…`` arrive on a socket and thread of their
  own, so a large echo or point cloud in conversion never delays the clock or a state.
- **QoS.** Each entry's profile (config.py); publishers are reliable by default, which both
  reliable and best-effort subscribers match. A ROS 2 node that asks for what a publisher or
  subscription does not offer gets a warning in the bridge's log naming the topic and the
  policy, and is counted (``qos_incompatible``) — never silence.
- **Lazy** entries convert only while a ROS 2 subscription is matched. Each publisher keeps its
  count of matched subscriptions from DDS's match events rather than asking rmw for it with
  every message, so a subscriber gets every message from the moment its match is reported; a
  lazy transient-local entry publishes the last message it saw as soon as its first subscriber
  matches.
- **Domain and discovery.** ``ROS_DOMAIN_ID``: ``ros_domain_id``, else the environment's, else
  echoloop's domain number (domain N ↔ ROS domain N). ``discovery``: ``localhost`` (default,
  unless ``ROS_AUTOMATIC_DISCOVERY_RANGE`` says otherwise), ``subnet``, ``off`` or
  ``system_default``. ``dds_transport: udp`` (default) keeps Fast DDS off shared memory, so a
  killed bridge leaves no ``/dev/shm/fastdds_*`` files: ``localhost`` is then the participant
  profile :data:`PROFILE` (UDP on 127.0.0.1 only; rmw's own localhost range would add shared
  memory), other ranges get ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``. ``default`` lets Fast DDS
  choose (shared memory between processes of one host).
- **Executor.** rclpy's ``EventsExecutor`` serves the ROS 2 side (commands in, QoS and match
  events): its wait loop runs in C++, so it neither burns nor waits for the interpreter lock
  the receive threads hold (the ``SingleThreadedExecutor`` it replaced, whose wait loop is
  Python, gave higher state and command latencies in ``python -m bench ros2``).
- **Shutdown.** The executor stops before the context is shut down; no ROS log files are
  written (``--disable-external-lib-logs``, no ``/rosout``).
- **Where a state's time goes.** ``stats()`` gives, per state, ``state_bus_ms`` (echoloop
  publish → received here, the bus's part) and ``state_out_ms`` (echoloop publish → its
  ``Odometry`` handed to DDS, the bus's part plus the bridge's), percentiles of the last
  :data:`LATENCY_SAMPLES`; what a ROS 2 subscriber sees beyond that is DDS's. Meaningful when
  the publisher runs on this host (its monotonic clock stamps ``pub_ns``).
"""

from __future__ import annotations

import functools
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hil_bridge.bus.faults import Faults
from ros2_bridge.config import DEFAULT_MAPPING, FAST_PREFIXES, ID, Mapping, load_mapping

__all__ = ["DISCOVERY", "Ros2Bridge"]

log = logging.getLogger(__name__)

#: ``discovery`` parameter -> ``ROS_AUTOMATIC_DISCOVERY_RANGE``
DISCOVERY = {"localhost": "LOCALHOST", "subnet": "SUBNET", "off": "OFF",
             "system_default": "SYSTEM_DEFAULT"}
#: most bus messages forwarded as one batch
BATCH = 256
#: states whose latencies ``stats()`` summarises (the latest)
LATENCY_SAMPLES = 20_000
#: the Fast DDS profile of ``discovery: localhost`` over UDP (loopback only, no shared memory)
PROFILE = Path(__file__).with_name("fastdds_localhost.xml")
_COUNTERS = ("bus_received", "bus_decode_errors", "published", "lazy_skipped",
             "not_convertible", "qos_incompatible", "cmd_received", "cmd_forwarded",
             "cmd_bad", "ros_publishers", "ros_subscriptions")


class _Out:
    """One ROS 2 publisher of one entry (a bus topic, or many under one ROS 2 topic)."""

    __slots__ = ("entry", "keeps_last", "last", "next_ok", "pub", "subscribers", "topic")

    def __init__(self, entry: Mapping, pub: Any, topic: str) -> None:
        self.entry, self.pub, self.topic = entry, pub, topic
        self.next_ok = 0.0
        #: matched ROS 2 subscriptions, as the last match event (or the count at creation) said
        self.subscribers = 0
        #: a lazy transient-local entry keeps its last message for its first subscriber
        self.keeps_last = entry.lazy and entry.qos.durability == "transient_local"
        self.last: tuple[str, Any] | None = None


class Ros2Bridge:
    """Launchable ROS 2 bridge (module docstring). ``mapping``: a YAML file path or a list of
    entries (config.py); None is :data:`~ros2_bridge.config.DEFAULT_MAPPING`."""

    def __init__(
        self,
        name: str,
        *,
        bus: str,
        mapping: str | Sequence[dict[str, Any]] | None = None,
        world_frame: str = "map",
        ros_domain_id: int | None = None,
        discovery: str | None = None,
        dds_transport: str = "udp",
    ) -> None:
        from ros2_bridge.config import mapping_from_data

        if mapping is None:
            self.mapping: tuple[Mapping, ...] = DEFAULT_MAPPING
        elif isinstance(mapping, str | os.PathLike):
            self.mapping = load_mapping(Path(mapping))
        else:
            self.mapping = mapping_from_data(list(mapping), where="mapping")
        if discovery is not None and discovery not in DISCOVERY:
            raise ValueError(f"discovery: expected one of {sorted(DISCOVERY)}, got {discovery!r}")
        if dds_transport not in ("udp", "default"):
            raise ValueError(f"dds_transport: expected 'udp' or 'default', got {dds_transport!r}")
        if ros_domain_id is not None and not 0 <= ros_domain_id <= 232:
            raise ValueError(f"ros_domain_id: expected 0..232, got {ros_domain_id}")
        if not world_frame:
            raise ValueError("world_frame: expected a frame name")
        self.name, self.bus = name, bus
        self.world_frame = world_frame
        self.ros_domain_id = ros_domain_id
        self.discovery = discovery
        self.dds_transport = dds_transport
        self.faults = Faults(name)
        self._c = dict.fromkeys(_COUNTERS, 0)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._transports: list[Any] = []
        self._routes: dict[str, list[tuple[_Out, str]]] = {}
        self._make_lock = threading.Lock()
        self._by_ros_topic: dict[str, _Out] = {}
        self._cmd_ids: set[tuple[str, str]] = set()
        self._cmd_pubs: dict[str, Any] = {}
        self._last_state: dict[str, tuple[int, int]] = {}
        self._state_bus_ms: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self._state_out_ms: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self._qos_warned: set[tuple[str, str]] = set()
        self._ctx: Any = None
        self._node: Any = None
        self._executor: Any = None
        self._bus_node: Any = None
        self._converter: Any = None
        self.domain_id: int | None = None
        self.discovery_used: str | None = None

    # ------------------------------------------------------------------ launchable contract

    def start(self) -> None:
        self._configure_environment()
        try:
            import rclpy
            from rclpy.experimental import EventsExecutor
        except ImportError as exc:
            raise ImportError(f"{self.name}: the ROS 2 bridge needs rclpy: pip install "
                              f"'echoloop[ros2]' (Linux x86-64) ({exc})") from exc
        from hil_bridge.bus.node import Node
        from hil_bridge.bus.transport import open_transport
        from ros2_bridge.convert import Converter

        self._converter = Converter(self.world_frame)
        self._ctx = rclpy.Context()
        rclpy.init(args=["--ros-args", "--disable-external-lib-logs"], context=self._ctx,
                   domain_id=self.domain_id)
        self._node = rclpy.create_node(self.name, context=self._ctx, enable_rosout=False,
                                       start_parameter_services=False)
        self._executor = EventsExecutor(context=self._ctx)
        self._executor.add_node(self._node)
        self._bus_node = Node(self.name, bus=self.bus, diagnostics_period_s=0,
                              faults=self.faults).start()
        fast, slow = open_transport(self.bus), open_transport(self.bus)
        self._transports = [fast, slow]
        prefixes = {m.prefix for m in self.mapping if m.direction == "ECHOLOOP_TO_ROS"}
        prefixes |= {m.echoloop_topic.partition(ID)[0].encode() for m in self.mapping
                     if m.direction == "ROS_TO_ECHOLOOP" and ID in m.echoloop_topic}
        for prefix in sorted(prefixes):
            is_fast = any(prefix.startswith(p.encode()) or p.encode().startswith(prefix)
                          for p in FAST_PREFIXES)
            (fast if is_fast else slow).subscribe(prefix)
        self._threads = [
            threading.Thread(target=self.faults.guarded("ROS 2 executor", self._spin),
                             name=f"{self.name}-ros", daemon=True),
            threading.Thread(target=self.faults.guarded("state receive loop",
                                                        lambda: self._rx_loop(fast)),
                             name=f"{self.name}-rx-fast", daemon=True),
            threading.Thread(target=self.faults.guarded("receive loop",
                                                        lambda: self._rx_loop(slow)),
                             name=f"{self.name}-rx", daemon=True),
        ]
        for t in self._threads:
            t.start()
        log.info("%s (pid %d): ROS 2 domain %d, discovery %s, DDS transport %s, %d topic "
                 "entries", self.name, os.getpid(), self.domain_id, self.discovery_used,
                 self.dds_transport, len(self.mapping))

    def stop(self) -> None:
        self._stop.set()
        for transport in self._transports:
            transport.wakeup()
        if self._executor is not None:
            self._executor.shutdown(timeout_sec=2.0)
        for t in self._threads:
            t.join()
        self._threads = []
        for transport in self._transports:
            transport.close()
        self._transports = []
        if self._bus_node is not None:
            self._bus_node.stop()
        if self._node is not None:
            self._node.destroy_node()
            self._node = None
        if self._ctx is not None:
            self._ctx.try_shutdown()
            self._ctx = None

    def failure(self, *, final: bool = False) -> str | None:
        """Why the bridge failed (one of its threads died), or None."""
        return self.faults.failure(final=final)

    def stats(self) -> dict[str, Any]:
        from hil_bridge.bus.stats import percentiles

        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["ros_topics"] = sorted(self._by_ros_topic)
            bus_ms, out_ms = list(self._state_bus_ms), list(self._state_out_ms)
        out["state_bus_ms"] = percentiles(bus_ms)
        out["state_out_ms"] = percentiles(out_ms)
        out["ros_domain_id"] = self.domain_id
        out["discovery"] = self.discovery_used
        return out

    # ------------------------------------------------------------------ set-up

    def _configure_environment(self) -> None:
        """ROS 2's process environment, before rclpy exists (module docstring)."""
        from hil_bridge.bus.domain import current as current_domain

        if self.ros_domain_id is not None:
            self.domain_id = self.ros_domain_id
        elif os.environ.get("ROS_DOMAIN_ID", "").strip():
            text = os.environ["ROS_DOMAIN_ID"].strip()
            if not text.isdigit() or not 0 <= int(text) <= 232:
                raise ValueError(f"ROS_DOMAIN_ID: expected 0..232, got {text!r}")
            self.domain_id = int(text)
        else:
            self.domain_id = current_domain().number or 0
        discovery = self.discovery
        if discovery is None:
            given = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper()
            discovery = {v: k for k, v in DISCOVERY.items()}.get(given, "localhost")
        self.discovery_used = discovery
        os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
        if discovery == "localhost" and self.dds_transport == "udp":
            # rmw's own LOCALHOST range adds a shared-memory transport: the profile gives
            # loopback UDP alone, and the range is left to it
            os.environ.setdefault("FASTDDS_DEFAULT_PROFILES_FILE", str(PROFILE))
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
            return
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = DISCOVERY[discovery]
        if self.dds_transport == "udp":
            os.environ["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"

    def _qos(self, entry: Mapping) -> Any:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        return QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=entry.qos.depth,
            reliability=(ReliabilityPolicy.RELIABLE if entry.qos.reliability == "reliable"
                         else ReliabilityPolicy.BEST_EFFORT),
            durability=(DurabilityPolicy.TRANSIENT_LOCAL
                        if entry.qos.durability == "transient_local"
                        else DurabilityPolicy.VOLATILE))

    def _on_incompatible(self, side: str, topic: str, entry: Mapping) -> Any:
        def warn(info: Any) -> None:
            kind = info.last_policy_kind
            policy = getattr(kind, "name", str(kind)).removeprefix("RMW_QOS_POLICY_")
            with self._lock:
                self._c["qos_incompatible"] += 1
                first = (topic, policy) not in self._qos_warned
                self._qos_warned.add((topic, policy))
            if first:
                q = entry.qos
                log.warning("%s: a ROS 2 %s of %s asks for an incompatible QoS (%s): it gets "
                            "nothing from this bridge, which offers reliability %s, durability "
                            "%s, depth %d", self.name, side, topic, policy, q.reliability,
                            q.durability, q.depth)

        return warn

    def _publisher(self, entry: Mapping, ident: str) -> _Out:
        from rclpy.event_handler import PublisherEventCallbacks

        from ros2_bridge.convert import ROS_TYPES

        topic = entry.ros_name(ident)
        out = self._by_ros_topic.get(topic)
        if out is None:
            callbacks = PublisherEventCallbacks(
                incompatible_qos=self._on_incompatible("subscription", topic, entry),
                matched=functools.partial(self._on_matched, topic))
            pub = self._node.create_publisher(ROS_TYPES[entry.ros_type], topic,
                                              self._qos(entry), event_callbacks=callbacks)
            out = _Out(entry, pub, topic)
            with self._lock:
                self._by_ros_topic[topic] = out
                self._c["ros_publishers"] += 1
            # a match reported before ``out`` was registered is in this count; later ones
            # set it (each event carries the current count)
            out.subscribers = pub.get_subscription_count()
        return out

    def _command_subscription(self, entry: Mapping, ident: str) -> None:
        from rclpy.event_handler import SubscriptionEventCallbacks

        from ros2_bridge.convert import ROS_TYPES

        ros_topic, bus_topic = entry.ros_name(ident), entry.echoloop_name(ident)
        glider = int(ident) if ident else 0
        callbacks = SubscriptionEventCallbacks(
            incompatible_qos=self._on_incompatible("publisher", ros_topic, entry))
        self._node.create_subscription(
            ROS_TYPES[entry.ros_type], ros_topic,
            lambda msg: self._on_command(msg, bus_topic, glider), self._qos(entry),
            event_callbacks=callbacks)
        with self._lock:
            self._c["ros_subscriptions"] += 1

    # ------------------------------------------------------------------ threads

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        try:
            while not self._stop.is_set():
                self._executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:
            return

    def _rx_loop(self, transport: Any) -> None:
        """Receive, then take whatever else is already waiting (at most :data:`BATCH`) and
        forward it as one batch: the states' frame algebra runs once per batch."""
        from hil_bridge.bus.codec import decode
        from hil_bridge.bus.messages import GliderState
        from hil_bridge.errors import CodecError, HilError

        while not self._stop.is_set():
            try:
                frames = transport.recv(timeout=0.1)
                if frames is None:
                    continue
                waiting = [(frames, time.monotonic_ns())]
                while len(waiting) < BATCH:
                    more = transport.recv(timeout=0)
                    if more is None:
                        break
                    waiting.append((more, time.monotonic_ns()))
            except HilError:
                return
            batch = []
            bus_ms = []
            for item, received_ns in waiting:
                try:
                    envelope = decode(item)
                except CodecError:
                    with self._lock:
                        self._c["bus_decode_errors"] += 1
                    continue
                batch.append((envelope.topic, envelope.msg, envelope.header.pub_ns))
                if type(envelope.msg) is GliderState:
                    bus_ms.append((received_ns - envelope.header.pub_ns) / 1e6)
            with self._lock:
                self._c["bus_received"] += len(batch)
                self._state_bus_ms.extend(bus_ms)
            self._forward(batch)

    def _forward(self, batch: list[tuple[str, Any, int]]) -> None:
        """Publish each bus message of ``batch`` (topic, message, its ``pub_ns``) on every ROS 2
        topic it maps to, in order."""
        from hil_bridge.bus.messages import GliderState

        states = [msg for _, msg, _ in batch if isinstance(msg, GliderState)]
        if states:
            self._converter.prepare(states)
        out_ms = []
        for topic, msg, pub_ns in batch:
            is_state = isinstance(msg, GliderState)
            if is_state:
                self._last_state[topic.rsplit("/", 1)[0]] = (msg.stamp_ns, msg.step)
            routes = self._routes.get(topic)
            if routes is None:
                routes = self._route(topic)
            for out, ident in routes:
                if self._publish(out, ident, msg) and is_state and (
                        out.entry.ros_type == "nav_msgs/msg/Odometry"):
                    out_ms.append((time.monotonic_ns() - pub_ns) / 1e6)
        if out_ms:
            with self._lock:
                self._state_out_ms.extend(out_ms)

    def _route(self, topic: str) -> list[tuple[_Out, str]]:
        """The first time ``topic`` is seen: its ROS 2 publishers, and the command
        subscriptions of the glider it names."""
        with self._make_lock:
            routes: list[tuple[_Out, str]] = []
            for entry in self.mapping:
                if entry.direction == "ROS_TO_ECHOLOOP":
                    self._discover_command(entry, topic)
                    continue
                ident = entry.match(topic)
                if ident is not None:
                    routes.append((self._publisher(entry, ident), ident))
            self._routes[topic] = routes
            return routes

    def _publish(self, out: _Out, ident: str, msg: Any) -> bool:
        """Convert and publish ``msg`` on ``out`` unless its rate limit, laziness or type say
        not to; True if it was published."""
        entry = out.entry
        if out.keeps_last:
            out.last = (ident, msg)
        if entry.max_rate_hz is not None:
            now = time.monotonic()
            if now < out.next_ok:
                return False
            out.next_ok = now + 1.0 / entry.max_rate_hz
        if entry.lazy and out.subscribers == 0:
            with self._lock:
                self._c["lazy_skipped"] += 1
            return False
        try:
            ros_msg = self._converter.convert(entry.ros_type, ident, msg, out.topic)
        except TypeError:
            ros_msg = None
        if ros_msg is None:
            with self._lock:
                self._c["not_convertible"] += 1
            return False
        out.pub.publish(ros_msg)
        with self._lock:
            self._c["published"] += 1
        return True

    def _on_matched(self, topic: str, info: Any) -> None:
        """Keep the count of matched subscriptions; a lazy transient-local topic gives a new
        subscriber the last message at once."""
        out = self._by_ros_topic.get(topic)
        if out is None:
            return
        out.subscribers = info.current_count
        if not out.keeps_last or out.last is None or info.current_count_change <= 0:
            return
        ident, msg = out.last
        self._publish(out, ident, msg)

    def _discover_command(self, entry: Mapping, topic: str) -> None:
        head, has_id, _ = entry.echoloop_topic.partition(ID)
        if has_id:
            if not topic.startswith(head):
                return
            ident = topic[len(head):].split("/", 1)[0]
            if not ident.isdigit():
                return
        else:
            ident = ""
        key = (entry.ros_topic, ident)
        if key not in self._cmd_ids:
            self._cmd_ids.add(key)
            self._command_subscription(entry, ident)

    def _on_command(self, msg: Any, bus_topic: str, glider: int) -> None:
        from hil_bridge.bus.messages import GliderCmd
        from hil_bridge.bus.qos import COMMAND
        from ros2_bridge.convert import CommandError, command_from_ros

        stamp_ns, step = self._last_state.get(bus_topic.rsplit("/", 1)[0], (0, 0))
        with self._lock:
            self._c["cmd_received"] += 1
        try:
            cmd = command_from_ros(msg, glider_id=glider, stamp_ns=stamp_ns, step=step)
        except CommandError as exc:
            with self._lock:
                self._c["cmd_bad"] += 1
                first = self._c["cmd_bad"] == 1
            if first:
                log.warning("%s: dropped a command on the ROS 2 side of %s: %s", self.name,
                            bus_topic, exc)
            return
        pub = self._cmd_pubs.get(bus_topic)
        if pub is None:
            pub = self._cmd_pubs[bus_topic] = self._bus_node.create_publisher(
                GliderCmd, bus_topic, COMMAND)
        pub.publish(cmd)
        with self._lock:
            self._c["cmd_forwarded"] += 1
