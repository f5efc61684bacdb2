"""The bridge's topic mapping (ros2_bridge.config): the default one, and bad entries refused at
load with the key and the expected form. No ROS import here."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
import yaml

from ros2_bridge.config import DEFAULT_MAPPING, load_mapping, mapping_from_data
from sim_core.config import ConfigError


def _entry(**changes: Any) -> dict[str, Any]:
    entry: dict[str, Any] = {"echoloop_topic": "/glider/<id>/state",
                             "ros_topic": "/glider_<id>/odom",
                             "ros_type": "nav_msgs/msg/Odometry"}
    entry.update(changes)
    return entry


def test_the_default_mapping_round_trips_through_yaml(tmp_path: Path) -> None:
    path = tmp_path / "mapping.yaml"
    path.write_text(yaml.safe_dump([dataclasses.asdict(m) for m in DEFAULT_MAPPING]))
    assert load_mapping(path) == DEFAULT_MAPPING


def test_the_default_mapping_carries_what_the_issue_lists() -> None:
    by_ros = {(m.ros_topic, m.ros_type) for m in DEFAULT_MAPPING}
    assert ("/clock", "rosgraph_msgs/msg/Clock") in by_ros
    assert ("/glider_<id>/odom", "nav_msgs/msg/Odometry") in by_ros
    assert ("/glider_<id>/imu", "sensor_msgs/msg/Imu") in by_ros
    assert ("/sonar_<id>/echo", "sensor_msgs/msg/Image") in by_ros
    assert ("/sonar_<id>/pose", "geometry_msgs/msg/PoseStamped") in by_ros
    assert ("/forest/points", "sensor_msgs/msg/PointCloud2") in by_ros
    assert ("/thermals", "visualization_msgs/msg/MarkerArray") in by_ros
    assert ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray") in by_ros
    [cmd] = [m for m in DEFAULT_MAPPING if m.direction == "ROS_TO_ECHOLOOP"]
    assert (cmd.ros_topic, cmd.ros_type) == ("/glider_<id>/cmd", "std_msgs/msg/Float64MultiArray")
    latched = {m.ros_topic for m in DEFAULT_MAPPING if m.qos.durability == "transient_local"}
    assert latched == {"/forest/points", "/thermals"}
    # publishers are reliable: best-effort and reliable subscribers both match
    assert all(m.qos.reliability == "reliable" for m in DEFAULT_MAPPING)


def test_ids_are_matched_and_substituted() -> None:
    odom = mapping_from_data([_entry()], where="m")[0]
    assert odom.match("/glider/12/state") == "12"
    assert odom.match("/glider/x/state") is None
    assert odom.match("/glider/12/neighbors") is None
    assert odom.ros_name("12") == "/glider_12/odom"
    assert odom.prefix == b"/glider/"
    clock = mapping_from_data([_entry(echoloop_topic="/clock", ros_topic="/clock",
                                      ros_type="rosgraph_msgs/msg/Clock")], where="m")[0]
    assert clock.prefix == b"/clock\0" and clock.match("/clock") == ""


@pytest.mark.parametrize(("entry", "message"), [
    (_entry(colour="red"), r"m\[0\]: unknown key\(s\) \['colour'\]"),
    (_entry(ros_topic="/glider/<id>/odom"), "no token may start with a digit"),
    (_entry(ros_type="nav_msgs/Odometry"), "expected 'package/msg/Type'"),
    (_entry(ros_type="sensor_msgs/msg/LaserScan"), "is not bridged ECHOLOOP_TO_ROS"),
    (_entry(echoloop_topic="/glider/0/state"), "holds <id> but '/glider/0/state'"),
    (_entry(direction="BOTH"), r"m\[0\].direction: expected one of"),
    (_entry(qos={"reliability": "sometimes"}), r"m\[0\].qos.reliability: expected one of"),
    (_entry(qos={"depth": 0}), "qos.depth: expected 1..10000"),
    (_entry(max_rate_hz=0), "max_rate_hz: expected > 0"),
    (_entry(echoloop_topic="/glider/<id>/cmd", ros_topic="/glider_<id>/cmd",
            ros_type="std_msgs/msg/Float64MultiArray", direction="ROS_TO_ECHOLOOP",
            lazy=True), "lazy and max_rate_hz apply to ECHOLOOP_TO_ROS"),
    (_entry(echoloop_topic="/glider//state"), "echoloop_topic: invalid topic"),
])
def test_a_bad_entry_is_refused_naming_the_key(entry: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        mapping_from_data([entry], where="m")


def test_two_entries_cannot_feed_one_bus_command_topic_from_one_ros_topic() -> None:
    cmd = {"echoloop_topic": "/glider/<id>/cmd", "ros_topic": "/glider_<id>/cmd",
           "ros_type": "std_msgs/msg/Float64MultiArray", "direction": "ROS_TO_ECHOLOOP"}
    with pytest.raises(ConfigError, match=r"m\[1\]: ros_topic '/glider_<id>/cmd' is already"):
        mapping_from_data([cmd, cmd], where="m")


@pytest.mark.parametrize("text", ["[]", "{a: 1}", "- 3"])
def test_a_mapping_file_that_is_not_a_list_of_entries_names_the_file(tmp_path: Path,
                                                                     text: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=str(path)):
        load_mapping(path)


def test_echoloop_ros2_mapping_prints_the_default_as_a_loadable_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from hil_bridge.cli import main

    assert main(["ros2", "mapping"]) == 0
    path = tmp_path / "mapping.yaml"
    path.write_text(capsys.readouterr().out)
    assert load_mapping(path) == DEFAULT_MAPPING
