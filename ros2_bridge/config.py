"""The bridge's topic mapping: a YAML list of entries, as ``ros_gz_bridge`` takes, validated once.

Each entry (every key but the topics and the type has a default)::

    - echoloop_topic: /glider/<id>/state      # <id>: any numeric id (the ids are discovered)
      ros_topic: /glider_<id>/odom            # a ROS 2 name: no token starts with a digit
      ros_type: nav_msgs/msg/Odometry
      direction: ECHOLOOP_TO_ROS              # or ROS_TO_ECHOLOOP
      qos: {reliability: reliable, durability: volatile, depth: 10}
      lazy: false                             # true: convert only while a ROS 2 node listens
      max_rate_hz: null                       # ECHOLOOP_TO_ROS: at most this many per topic

:data:`DEFAULT_MAPPING` is what the bridge does without a file (docs/ros2.md tabulates it).
This module imports no ROS: the launch checks a mapping before any node exists.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from hil_bridge.bus.codec import validate_topic
from hil_bridge.files.config import load_yaml
from sim_core.config import ConfigError, from_dict

__all__ = [
    "CONVERSIONS",
    "DEFAULT_MAPPING",
    "FAST_PREFIXES",
    "Mapping",
    "QoS",
    "load_mapping",
    "mapping_from_data",
]

ID = "<id>"

#: (echoloop message type, ROS 2 type) pairs the bridge converts, per direction
CONVERSIONS: dict[str, frozenset[tuple[str, str]]] = {
    "ECHOLOOP_TO_ROS": frozenset({
        ("echoloop/Clock", "rosgraph_msgs/msg/Clock"),
        ("echoloop/GliderState", "nav_msgs/msg/Odometry"),
        ("echoloop/GliderState", "sensor_msgs/msg/Imu"),
        ("echoloop/GliderState", "geometry_msgs/msg/PoseStamped"),
        ("echoloop/GliderState", "visualization_msgs/msg/MarkerArray"),
        ("echoloop/SonarEcho", "sensor_msgs/msg/Image"),
        ("echoloop/SonarEcho", "geometry_msgs/msg/PoseStamped"),
        ("echoloop/SonarEcho", "diagnostic_msgs/msg/DiagnosticArray"),
        ("echoloop/SonarEcho", "visualization_msgs/msg/MarkerArray"),
        ("echoloop/PointCloud", "sensor_msgs/msg/PointCloud2"),
        ("echoloop/ThermalMarkers", "visualization_msgs/msg/MarkerArray"),
        ("echoloop/Diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
    }),
    "ROS_TO_ECHOLOOP": frozenset({
        ("echoloop/GliderCmd", "std_msgs/msg/Float64MultiArray"),
    }),
}

#: bus topics the bridge reads on its own socket and thread, ahead of echoes and point clouds
#: (the clock is never delayed behind an echo's conversion)
FAST_PREFIXES = ("/clock", "/glider/")

_ROS_TYPE = re.compile(r"^[a-z][a-z0-9_]*/msg/[A-Z][A-Za-z0-9]*$")


@dataclass(frozen=True)
class QoS:
    """A ROS 2 QoS profile: reliability, durability and keep-last depth."""

    reliability: Literal["reliable", "best_effort"] = "reliable"
    durability: Literal["volatile", "transient_local"] = "volatile"
    depth: int = 10

    def __post_init__(self) -> None:
        if not 1 <= self.depth <= 10_000:
            raise ValueError(f"qos.depth: expected 1..10000, got {self.depth}")


@dataclass(frozen=True)
class Mapping:
    """One bridged topic (module docstring)."""

    echoloop_topic: str
    ros_topic: str
    ros_type: str
    direction: Literal["ECHOLOOP_TO_ROS", "ROS_TO_ECHOLOOP"] = "ECHOLOOP_TO_ROS"
    qos: QoS = dataclasses.field(default_factory=QoS)
    lazy: bool = False
    max_rate_hz: float | None = None

    def __post_init__(self) -> None:
        for key in ("echoloop_topic", "ros_topic"):
            topic = getattr(self, key)
            if topic.count(ID) > 1:
                raise ValueError(f"{key}: at most one {ID} expected, got {topic!r}")
            try:
                validate_topic(topic.replace(ID, "0"))
            except ValueError as exc:
                raise ValueError(f"{key}: {exc}") from None
        source, target = ((self.echoloop_topic, self.ros_topic)
                          if self.direction == "ECHOLOOP_TO_ROS"
                          else (self.ros_topic, self.echoloop_topic))
        if ID in target and ID not in source:
            raise ValueError(f"{target!r} holds {ID} but {source!r}, where it comes from, "
                             "does not")
        if any(token[:1].isdigit() for token in self.ros_topic.replace(ID, "0").split("/")):
            raise ValueError(f"ros_topic: {self.ros_topic!r} is not a ROS 2 name: no token may "
                             "start with a digit (write /glider_<id>/odom, not /glider/<id>/odom)")
        if not _ROS_TYPE.match(self.ros_type):
            raise ValueError(f"ros_type: expected 'package/msg/Type', got {self.ros_type!r}")
        if self.ros_type not in {ros for _, ros in CONVERSIONS[self.direction]}:
            known = sorted({ros for _, ros in CONVERSIONS[self.direction]})
            raise ValueError(f"ros_type: {self.ros_type!r} is not bridged {self.direction}; "
                             f"expected one of {known}")
        if self.max_rate_hz is not None and not self.max_rate_hz > 0:
            raise ValueError(f"max_rate_hz: expected > 0 or null, got {self.max_rate_hz}")
        if self.direction == "ROS_TO_ECHOLOOP" and (self.lazy or self.max_rate_hz is not None):
            raise ValueError("lazy and max_rate_hz apply to ECHOLOOP_TO_ROS entries only")

    @property
    def prefix(self) -> bytes:
        """The bus subscription that receives this entry's topics (a topic frame, or the
        frame's prefix up to ``<id>``)."""
        head, has_id, _ = self.echoloop_topic.partition(ID)
        return head.encode() if has_id else self.echoloop_topic.encode() + b"\0"

    def match(self, topic: str) -> str | None:
        """The id ``topic`` fills ``<id>`` with ('' when the entry has none), or None when
        ``topic`` is not this entry's."""
        head, has_id, tail = self.echoloop_topic.partition(ID)
        if not has_id:
            return "" if topic == self.echoloop_topic else None
        if not (topic.startswith(head) and topic.endswith(tail)):
            return None
        middle = topic[len(head): len(topic) - len(tail)]
        return middle if middle.isdigit() else None

    def ros_name(self, ident: str) -> str:
        """The ROS 2 topic of the bus topic whose id is ``ident``."""
        return self.ros_topic.replace(ID, ident)

    def echoloop_name(self, ident: str) -> str:
        """The bus topic whose id is ``ident``."""
        return self.echoloop_topic.replace(ID, ident)


def _entry(echoloop: str, ros: str, ros_type: str, *, lazy: bool = False,
           latched: bool = False, depth: int = 10, max_rate_hz: float | None = None,
           direction: str = "ECHOLOOP_TO_ROS") -> Mapping:
    qos = QoS(durability="transient_local" if latched else "volatile", depth=depth)
    return from_dict(Mapping, {"echoloop_topic": echoloop, "ros_topic": ros,
                               "ros_type": ros_type, "direction": direction,
                               "qos": dataclasses.asdict(qos), "lazy": lazy,
                               "max_rate_hz": max_rate_hz})


#: what the bridge does without a mapping file (docs/ros2.md)
DEFAULT_MAPPING: tuple[Mapping, ...] = (
    _entry("/clock", "/clock", "rosgraph_msgs/msg/Clock", depth=1),
    _entry("/glider/<id>/state", "/glider_<id>/odom", "nav_msgs/msg/Odometry"),
    _entry("/glider/<id>/state", "/glider_<id>/imu", "sensor_msgs/msg/Imu", lazy=True),
    _entry("/glider/<id>/state", "/echoloop/gliders", "visualization_msgs/msg/MarkerArray",
           lazy=True, max_rate_hz=10.0),
    _entry("/sonar/<id>/echo", "/sonar_<id>/echo", "sensor_msgs/msg/Image", lazy=True),
    _entry("/sonar/<id>/echo", "/sonar_<id>/echo_info", "diagnostic_msgs/msg/DiagnosticArray",
           lazy=True),
    _entry("/sonar/<id>/echo", "/sonar_<id>/pose", "geometry_msgs/msg/PoseStamped", lazy=True),
    _entry("/sonar/<id>/echo", "/echoloop/beams", "visualization_msgs/msg/MarkerArray",
           lazy=True),
    _entry("/forest/points", "/forest/points", "sensor_msgs/msg/PointCloud2", latched=True,
           depth=1),
    _entry("/thermals", "/thermals", "visualization_msgs/msg/MarkerArray", latched=True,
           depth=1),
    _entry("/diagnostics", "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", lazy=True),
    _entry("/glider/<id>/cmd", "/glider_<id>/cmd", "std_msgs/msg/Float64MultiArray",
           direction="ROS_TO_ECHOLOOP"),
)


def mapping_from_data(data: Any, *, where: str) -> tuple[Mapping, ...]:
    """Validate a mapping (a list of entries); ``ConfigError`` naming ``where`` and the entry."""
    if not isinstance(data, list) or not data:
        raise ConfigError(f"{where}: expected a non-empty list of topic entries, got {data!r}")
    out = tuple(from_dict(Mapping, entry, path=f"{where}[{i}]") for i, entry in enumerate(data))
    seen: dict[tuple[str, str], int] = {}
    for i, m in enumerate(out):
        key = (m.direction, m.ros_topic)
        if m.direction == "ROS_TO_ECHOLOOP" and key in seen:
            raise ConfigError(f"{where}[{i}]: ros_topic {m.ros_topic!r} is already bridged "
                              f"into echoloop by entry {seen[key]}")
        seen.setdefault(key, i)
    return out


def load_mapping(path: str | Path) -> tuple[Mapping, ...]:
    """The mapping of YAML file ``path`` (module docstring)."""
    return mapping_from_data(load_yaml(path), where=str(path))
