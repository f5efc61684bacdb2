"""``echoloop topic``: rates from stamps, gaps from seq jumps, echo, list, info."""

from __future__ import annotations

import json
import threading

import pytest

from hil_bridge.bus.codec import encode
from hil_bridge.bus.messages import Clock, GliderState
from hil_bridge.bus.transport import open_transport
from hil_bridge.cli.topic import main as topic_main
from hil_bridge.tools.topic import TopicMonitor


def _publisher(bus: str, seqs: list[int], stop: threading.Event) -> threading.Thread:
    """Publish ``/g`` with the given seqs, stamps 10 ms apart, until the monitor stops us."""

    def run() -> None:
        with open_transport(bus) as raw:
            raw.wait_for_subscriber("/g", 10.0)
            for seq in seqs:
                raw.publish(encode("/g", Clock(stamp_ns=seq * 10_000_000), seq=seq, pub_ns=0,
                                   src="p"))
            stop.wait(10.0)

    thread = threading.Thread(target=run)
    thread.start()
    return thread


def test_monitor_computes_rate_from_stamps_and_gaps_from_seq() -> None:
    bus = "mem://topic_monitor"
    stop = threading.Event()
    seqs = [*range(10), *range(15, 20)]
    thread = _publisher(bus, seqs, stop)
    try:
        topics = TopicMonitor(bus, "/g\0").run(10.0, max_messages=len(seqs))
    finally:
        stop.set()
        thread.join()
    st = topics["/g"]
    assert (st.count, st.gaps, st.lost) == (15, 1, 5)
    assert st.rate_hz == pytest.approx(14 / 0.19)
    iv = st.interval_summary()
    assert iv is not None
    assert iv["min_s"] == pytest.approx(0.01) and iv["max_s"] == pytest.approx(0.06)


def test_topic_echo_and_hz_cli(capsys: pytest.CaptureFixture[str]) -> None:
    bus = "mem://topic_cli"
    stop = threading.Event()
    thread = _publisher(bus, [0, 1, 2, 5], stop)
    try:
        assert topic_main(["echo", "/g", "--bus", bus, "--count", "4", "--json", "--header",
                           "--duration", "10"]) == 0
    finally:
        stop.set()
        thread.join()
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [x["header"]["seq"] for x in lines] == [0, 1, 2, 5]
    assert lines[0]["msg"] == {"stamp_ns": 0, "lockstep": False}

    with open_transport(bus) as raw:
        state = GliderState(stamp_ns=0, x=0.0, y=0.0, z=0.0, heading=0.0, bank=0.0,
                            airspeed=0.0, vz=0.0)

        def feed() -> None:
            raw.wait_for_subscriber("/s", 10.0)
            for seq in (0, 1, 3):
                raw.publish(encode("/s", state, seq=seq, pub_ns=0, src="q"))

        feeder = threading.Thread(target=feed)
        feeder.start()
        try:
            assert topic_main(["hz", "/s", "--bus", bus, "--duration", "1.0", "--json"]) == 0
        finally:
            feeder.join()
    out = json.loads(capsys.readouterr().out)
    assert out["count"] == 3 and out["gaps"] == 1 and out["lost"] == 1


def test_topic_list_and_info_report_nothing_heard(capsys: pytest.CaptureFixture[str]) -> None:
    assert topic_main(["list", "--bus", "mem://silent", "--duration", "0.05"]) == 0
    assert "no messages heard" in capsys.readouterr().out
    assert topic_main(["info", "/x", "--bus", "mem://silent", "--duration", "0.05"]) == 0
    assert "no message on /x" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        topic_main(["echo", "bad topic"])
