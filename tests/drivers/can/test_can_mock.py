"""The mock autopilot: path follower, frame assembly, heartbeats and its CLI."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from typing import Any

import can
import numpy as np
import pytest

from drivers.can.codec import DecodedFrame, GliderCanCodec
from drivers.mocks.autopilot import AP_MODES, MockAutopilot
from drivers.mocks.autopilot_cli import main as cli_main
from drivers.mocks.path_follower import PathFollower, figure_eight_waypoints
from drivers.mocks.profile_receiver import ProfileReceiver
from tests.drivers.can._util import unique, wait_until

G = 9.81


def test_path_follower_closed_form() -> None:
    wp = np.array([[100.0, 0.0], [100.0, 100.0], [0.0, 100.0], [0.0, 0.0]])
    pf = PathFollower(wp, n_vehicles=3, lookahead_m=10.0, airspeed_mps=12.0,
                      bank_max_rad=math.radians(40))
    # vehicle 0 heads straight at the target, 1 has it 10° to the left, 2 has it 90° to the
    # right and flies fast enough for the bank limit: atan(2 * 30² / (100 g)) = 61° > 40°
    xy = np.zeros((3, 2))
    heading = np.array([0.0, -math.radians(10), math.pi / 2])
    bank, speed = pf.command(xy, heading, np.array([10.0, 10.0, 30.0]))
    assert pf.target_index is not None and list(pf.target_index) == [0, 0, 0]
    assert bank[0] == pytest.approx(0.0, abs=1e-12)
    expected = math.atan(2 * 10.0**2 * math.sin(math.radians(10)) / (100.0 * G))
    assert bank[1] == pytest.approx(expected, rel=1e-12) and bank[1] > 0
    assert bank[2] == pytest.approx(-math.radians(40))
    assert np.all(speed == 12.0)


def _fly(pf: PathFollower, xy: np.ndarray, psi: np.ndarray, v: float, seconds: float,
         dt: float = 0.05) -> tuple[np.ndarray, list[np.ndarray]]:
    """Coordinated-turn kinematics (heading rate = g tan(bank) / v) under the follower."""
    track = []
    for _ in range(int(seconds / dt)):
        bank, _ = pf.command(xy, psi, np.full(len(psi), v))
        psi = psi + G * np.tan(bank) / v * dt
        xy = xy + v * dt * np.stack([np.cos(psi), np.sin(psi)], axis=1)
        track.append(xy.copy())
    return xy, track


def _distance_to_route(points: np.ndarray, route: np.ndarray) -> np.ndarray:
    a, b = route, np.roll(route, -1, axis=0)
    ab = b - a
    t = np.clip(((points[:, None, :] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.min(np.linalg.norm(points[:, None, :] - closest, axis=-1), axis=1)


def test_path_follower_flies_the_figure_eight() -> None:
    route = figure_eight_waypoints(half_length_m=150.0, n=96)
    starts = np.array([[0.0, 0.0], [160.0, 20.0], [-120.0, -60.0]])
    pf = PathFollower(route, n_vehicles=3, lookahead_m=25.0, airspeed_mps=10.0,
                      bank_max_rad=math.radians(35))
    _, track = _fly(pf, starts.copy(), np.array([0.0, 1.0, -2.0]), 10.0, 150.0)
    late = np.concatenate(track[len(track) // 2:])
    assert _distance_to_route(late, route).max() < 8.0
    # every vehicle went round: its late track reaches both lobes (x < -100 and x > 100)
    per_vehicle = np.stack(track[len(track) // 2:], axis=1)
    assert np.all(per_vehicle[..., 0].min(axis=1) < -100)
    assert np.all(per_vehicle[..., 0].max(axis=1) > 100)


def test_path_follower_single_vehicle_is_a_row_of_the_batch() -> None:
    route = figure_eight_waypoints()
    xy = np.array([[5.0, 3.0], [-40.0, 10.0]])
    psi, v = np.array([0.4, 2.0]), np.array([9.0, 11.0])
    batch = PathFollower(route, n_vehicles=2).command(xy, psi, v)
    for i in range(2):
        one = PathFollower(route, n_vehicles=1).command(xy[i:i + 1], psi[i:i + 1], v[i:i + 1])
        assert one[0][0] == batch[0][i] and one[1][0] == batch[1][i]


def test_inactive_vehicles_do_not_advance() -> None:
    route = figure_eight_waypoints()
    pf = PathFollower(route, n_vehicles=2)
    xy = np.array([[5.0, 3.0], [0.0, 0.0]])
    bank, _ = pf.command(xy, np.array([0.4, 0.0]), np.array([9.0, 0.0]), active=[True, False])
    assert pf.target_index is not None and pf.target_index[1] == -1
    single = PathFollower(route, n_vehicles=1).command(xy[:1], [0.4], [9.0])
    assert bank[0] == single[0][0]
    pf.command(xy, np.array([0.4, 0.0]), np.array([9.0, 9.0]))
    assert pf.target_index[1] >= 0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"waypoints": [[0, 0]]}, "waypoints"), ({"lookahead_m": 0}, "lookahead_m"),
     ({"bank_max_rad": 2.0}, "bank_max_rad"), ({"airspeed_mps": -1}, "airspeed_mps")],
)
def test_path_follower_rejects_bad_params(kwargs: dict[str, Any], match: str) -> None:
    args = {"waypoints": figure_eight_waypoints()} | kwargs
    with pytest.raises(ValueError, match=match):
        PathFollower(**args)


CODEC = GliderCanCodec()


def _frame(name: str, node: int, **signals: float) -> DecodedFrame:
    return CODEC.decode(CODEC.encode(name, node, signals))


def _nb(slot: int, count: int, nb_set: int, dx: float) -> list[DecodedFrame]:
    return [
        _frame("NEIGHBOR_POS", 2, nb_slot=slot, nb_dx_m=dx, nb_dy_m=0.0, nb_dz_m=1.0),
        _frame("NEIGHBOR_MOTION", 2, nb_slot=slot, nb_count=count, nb_heading_rad=0.5,
               nb_airspeed_mps=9.0, nb_vz_mps=1.0, nb_set=nb_set),
    ]


def test_receiver_assembles_state_and_neighbour_lists() -> None:
    rx = ProfileReceiver([2])

    def motion(counter: int) -> DecodedFrame:
        return _frame("GLIDER_STATE_MOTION", 2, heading_rad=0.1, bank_rad=0.0, airspeed_mps=10.0,
                      vz_mps=0.5, alive=1, state_counter=counter)

    rx.feed(motion(1), 1.0)  # a sample without its POS
    assert rx.view(2).own is None and rx.counts()["samples_torn"] == 1
    rx.feed(_frame("GLIDER_STATE_POS", 2, x_m=10.0, y_m=20.0, z_m=300.0), 1.0)
    rx.feed(motion(2), 1.0)
    view = rx.view(2)
    assert view.own is not None and (view.own.x, view.own.z, view.alive) == (10.0, 300.0, True)
    for f in _nb(0, 2, 5, 50.0) + _nb(1, 2, 5, -30.0):
        rx.feed(f, 1.1)
    good = rx.view(2).neighbours
    assert good.shape == (2, 6) and list(good[:, 0]) == [60.0, -20.0] and good[0, 2] == 301.0
    # a list with a lost slot is discarded; the previous one stays
    for f in _nb(0, 3, 6, 1.0) + _nb(2, 3, 6, 2.0):
        rx.feed(f, 1.2)
    assert np.array_equal(rx.view(2).neighbours, good) and rx.counts()["nb_incomplete"] >= 1
    # an empty list is one NEIGHBOR_MOTION with nb_count = 0
    rx.feed(_frame("NEIGHBOR_MOTION", 2, nb_slot=0, nb_count=0, nb_heading_rad=0.0,
                   nb_airspeed_mps=0.0, nb_vz_mps=0.0, nb_set=7), 1.3)
    assert rx.view(2).neighbours.shape == (0, 6) and rx.view(2).neighbour_set == 7
    assert not rx.feed(_frame("GLIDER_STATE_POS", 3, x_m=0.0, y_m=0.0, z_m=0.0), 1.4)


class Bridge:
    """A hand-driven bridge on a raw virtual bus."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[DecodedFrame] = []
        self.counter = 0

    def state(self, node: int) -> None:
        """One state sample (POS, MOTION), the counter one up from the last."""
        self.counter += 1
        self.bus.send(CODEC.encode("GLIDER_STATE_POS", node, {"x_m": 5.0, "y_m": 0.0,
                                                              "z_m": 40.0}))
        self.bus.send(CODEC.encode("GLIDER_STATE_MOTION", node, {
            "heading_rad": math.pi / 2, "bank_rad": 0.0, "airspeed_mps": 10.0, "vz_mps": 0.0,
            "alive": 1, "state_counter": self.counter}))

    def drain(self) -> list[DecodedFrame]:
        while (msg := self.bus.recv(0.0)) is not None:
            self.frames.append(CODEC.decode(msg))
        return self.frames


@pytest.fixture
def bridge_and_mock() -> Iterator[tuple[Bridge, MockAutopilot]]:
    channel = unique("mock-")
    bridge = Bridge(channel)
    mock = MockAutopilot("mock", channel=channel, gliders=[4], controller="path", rate_hz=50.0,
                         heartbeat_hz=50.0, state_timeout_s=0.2)
    mock.start()
    yield bridge, mock
    mock.stop()
    bridge.bus.shutdown()


def test_mock_commands_only_with_fresh_state(
    bridge_and_mock: tuple[Bridge, MockAutopilot]
) -> None:
    bridge, mock = bridge_and_mock

    def modes() -> set[int]:
        return {int(f.signals["ap_mode"]) for f in bridge.drain()[-3:]
                if f.name == "AUTOPILOT_HEARTBEAT"}

    assert wait_until(lambda: AP_MODES["INIT"] in modes())
    assert not any(f.name == "AUTOPILOT_CMD" for f in bridge.drain())
    bridge.state(4)  # the first sample only gives the mock a counter to bind the next one to
    bridge.state(4)
    assert wait_until(lambda: any(f.name == "AUTOPILOT_CMD" and f.node_id == 4
                                  for f in bridge.drain()))
    cmd = next(f for f in bridge.frames if f.name == "AUTOPILOT_CMD")
    # at (5, 0) heading north, the figure-eight's nearest waypoint lies ahead-right or -left;
    # the command is the follower's for that state, at its airspeed
    assert cmd.signals["airspeed_cmd_mps"] == pytest.approx(10.0)
    last = mock.last_command(4)
    assert last is not None and abs(last[0] - cmd.signals["bank_cmd_rad"]) <= 0.5e-4 + 1e-9
    assert wait_until(lambda: AP_MODES["NO_STATE"] in modes())
    sent = mock.stats()["commands_sent"]
    bridge.drain()
    assert wait_until(lambda: modes() == {AP_MODES["NO_STATE"]})
    assert mock.stats()["commands_sent"] == sent
    assert mock.stats()["saturated_tx"] == 0  # e.g. the state age never goes negative


@pytest.mark.parametrize(
    ("params", "match"),
    [({"controller": "pid"}, "controller"), ({"gliders": [16]}, "0..15"),
     ({"gliders": "0,0"}, "unique"), ({"rate_hz": -1.0}, "rate_hz"),
     ({"faults": {"drop_rate": 2}}, "drop_rate"),
     ({"interface": "nope"}, "unknown python-can interface")],
)
def test_mock_rejects_bad_params(params: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        MockAutopilot("mock", **params)


def test_mock_cli_runs_and_summarises(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli_main(["--channel", unique("cli-"), "--gliders", "0,1", "--duration", "0.3",
                     "--every", "0.1", "--controller", "baseline"])
    out = capsys.readouterr().out
    assert code == 0
    assert "nodes [0, 1], controller baseline" in out
    assert "summary:" in out and "heartbeats_sent=" in out


def test_mock_cli_path_waypoints(tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "route.csv"
    good.write_text("0,0\n50,0\n50,50\n")
    assert cli_main(["--channel", unique("cli-"), "--controller", "path", "--waypoints",
                     str(good), "--duration", "0.1", "--every", "0"]) == 0
    assert "controller path, 10 Hz" in capsys.readouterr().out
    bad = tmp_path / "route.txt"
    bad.write_text("0 0 1\n50\n")
    with pytest.raises(ValueError, match="two numeric columns"):
        cli_main(["--channel", unique("cli-"), "--controller", "path", "--waypoints", str(bad),
                  "--duration", "0.1"])


@pytest.mark.parametrize("log", ["mock.db", "mock.log"])
def test_a_mock_whose_bus_is_refused_leaves_no_thread_and_no_log(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch, log: str,
) -> None:
    """A bus refused for good (an interface not usable here) fails the mock's start and the
    CLI with one line, and nothing of the link outlives it: python-can's writer thread of a
    ``.db`` log is no daemon, and left running it kept ``echoloop mock autopilot`` from ever
    exiting after its error."""
    def refused(self: object) -> can.BusABC:
        raise can.CanInterfaceNotImplementedError("no such driver here")

    monkeypatch.setattr("drivers.can.bus.CanLink._make_bus", refused)
    before = set(threading.enumerate())
    mock = MockAutopilot("mock", channel=unique("refused-"), can_log=tmp_path / log)
    with pytest.raises(ValueError, match="is not usable here: no such driver here"):
        mock.start()
    mock.stop()
    with pytest.raises(ValueError, match="is not usable here"):
        cli_main(["--channel", unique("cli-"), "--can-log", str(tmp_path / f"cli-{log}"),
                  "--duration", "0.1", "--every", "0"])
    assert [t.name for t in threading.enumerate() if t not in before] == []
    assert list(tmp_path.iterdir()) == []  # no log, not even its temporary file
