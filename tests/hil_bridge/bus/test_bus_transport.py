"""Transport conformance: one suite, run against every backend (``mem`` and ``zmq``)."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil_bridge import lifetime
from hil_bridge.bus.codec import decode, encode, encode_header
from hil_bridge.bus.messages import Clock, SonarEcho
from hil_bridge.bus.proxy import Proxy, proxy_for
from hil_bridge.bus.transport import BACKENDS, open_transport
from hil_bridge.bus.transport.zmq import parse_zmq_url
from hil_bridge.errors import TransportClosed
from tests.hil_bridge.busfixtures import open_bus


@pytest.fixture(params=["mem", "zmq"])
def bus_url(request: pytest.FixtureRequest) -> Iterator[str]:
    """The backends (composition is a node's: a composed bus's transport is the zmq one)."""
    with open_bus(request.param) as url:
        yield url


def _clock(topic: str, seq: int) -> list[bytes]:
    return encode(topic, Clock(stamp_ns=seq * 10), seq=seq, pub_ns=seq)


def test_delivers_in_order_after_wait_for_subscriber(bus_url: str) -> None:
    with open_transport(bus_url) as pub, open_transport(bus_url) as sub:
        sub.subscribe(b"/clock\0")
        assert pub.wait_for_subscriber("/clock", timeout=10.0)
        for i in range(200):
            pub.publish(_clock("/clock", i))
        got = [sub.recv(timeout=10.0) for _ in range(200)]
        assert [decode(f).header.seq for f in got if f is not None] == list(range(200))
        assert pub.stats()["sent"] == 200 and sub.stats()["received"] == 200


def test_prefix_filter_respects_the_nul_terminator(bus_url: str) -> None:
    with open_transport(bus_url) as pub, open_transport(bus_url) as sub:
        sub.subscribe(b"/glider/1/state\0")
        assert pub.wait_for_subscriber("/glider/1/state", timeout=10.0)
        assert not pub.has_subscriber("/glider/1/state_raw")
        pub.publish(_clock("/glider/1/state_raw", 0))
        pub.publish(_clock("/glider/1/state", 1))
        frames = sub.recv(timeout=10.0)
        assert frames is not None and frames[0] == b"/glider/1/state\0"
        assert sub.recv(timeout=0.05) is None


def test_publisher_receives_its_own_messages_when_subscribed(bus_url: str) -> None:
    with open_transport(bus_url) as t:
        t.subscribe("/a\0")
        assert t.wait_for_subscriber("/a", timeout=10.0)
        t.publish(_clock("/a", 0))
        frames = t.recv(timeout=10.0)
        assert frames is not None and decode(frames).topic == "/a"


def test_recv_times_out_and_wakeup_returns_none(bus_url: str) -> None:
    with open_transport(bus_url) as t:
        t.subscribe(b"")
        assert t.recv(timeout=0.01) is None
        t.wakeup()
        assert t.recv(timeout=10.0) is None


def test_unsubscribe_stops_delivery(bus_url: str) -> None:
    with open_transport(bus_url) as pub, open_transport(bus_url) as sub:
        sub.subscribe(b"/b\0")
        sub.subscribe(b"/a\0")
        assert pub.wait_for_subscriber("/a", timeout=10.0)
        assert pub.wait_for_subscriber("/b", timeout=10.0)
        sub.unsubscribe(b"/a\0")
        with pytest.raises(ValueError, match="not subscribed"):
            sub.unsubscribe(b"/a\0")
        pub.publish(_clock("/a", 0))
        pub.publish(_clock("/b", 0))
        frames = sub.recv(timeout=10.0)
        assert frames is not None and frames[0] == b"/b\0"


def test_reset_drops_the_queue_and_keeps_the_subscription(bus_url: str) -> None:
    """Contract 8. A reset drops what has reached the subscriber, not what is still on its
    way: a witness subscriber holding the backlog's last message shows that the bus has
    handed all of it to every subscriber (a proxy forwards to all of them at once)."""
    with (open_transport(bus_url) as pub, open_transport(bus_url) as sub,
          open_transport(bus_url) as witness):
        sub.subscribe(b"/a\0")
        witness.subscribe(b"/a\0")
        joined = {"sub": False, "witness": False}
        for i in range(500):  # until both have joined (each has received something)
            pub.publish(_clock("/a", i))
            joined["sub"] |= sub.recv(timeout=0.02) is not None
            joined["witness"] |= witness.recv(timeout=0.0) is not None
            if all(joined.values()):
                break
        assert all(joined.values())
        for i in range(600, 650):
            pub.publish(_clock("/a", i))
        last = -1
        while last != 649:
            frames = witness.recv(timeout=10.0)
            assert frames is not None
            last = decode(frames).header.seq
        sub.reset(b"/a\0")
        with pytest.raises(ValueError, match="not subscribed"):
            sub.reset(b"/b\0")
        seqs: list[int] = []
        for i in range(1000, 1200):  # after a reset over ZeroMQ the topic's socket rejoins
            pub.publish(_clock("/a", i))
            frames = sub.recv(timeout=0.02)
            while frames is not None:
                seqs.append(decode(frames).header.seq)
                frames = sub.recv(timeout=0.0)
            if seqs:
                break
        assert seqs and min(seqs) >= 1000  # nothing of the old backlog came back
        assert sub.stats()["resets"] == 1


def test_slow_subscriber_never_blocks_the_publisher(bus_url: str) -> None:
    # small queues on this subscriber; 8 KiB messages so that the proxy's queues and the
    # kernel's socket buffers (a few MiB) overflow too: n messages cannot all be held anywhere
    small = bus_url + ("&hwm=10" if "?" in bus_url else "?depth=10")
    with open_transport(bus_url) as pub, open_transport(small) as sub:
        sub.subscribe(b"/s\0")
        assert pub.wait_for_subscriber("/s", timeout=10.0)
        echo = SonarEcho(stamp_ns=0, ping_seq=0, fs=1.0, samples=np.zeros(2048, np.float32),
                         leaves_in_beam=0, fidelity="fast")
        payload = encode("/s", echo, seq=0, pub_ns=0)
        n = 8000  # 64 MiB in total
        for i in range(n):
            pub.publish([payload[0], encode_header(echo, seq=i, pub_ns=0), payload[2]])
        assert pub.stats()["sent"] == n
        seqs = []
        while (frames := sub.recv(timeout=0.5)) is not None:
            seqs.append(decode(frames).header.seq)
        assert 0 < len(seqs) < n, len(seqs)
        assert seqs == sorted(seqs)
        lost = n - len(seqs)
        # counted where the loss is visible: the mem queue counts it, zmq shows seq gaps
        gaps = sum(b - a - 1 for a, b in zip([-1, *seqs], [*seqs, n], strict=True))
        assert gaps == lost
        if "dropped" in sub.stats():
            assert sub.stats()["dropped"] == lost


def test_latecomer_learns_existing_subscriptions_and_on_subscribe_fires(bus_url: str) -> None:
    with open_transport(bus_url) as sub:
        sub.subscribe(b"/x\0")
        with open_transport(bus_url) as pub:
            assert pub.wait_for_subscriber("/x", timeout=10.0)
            seen: list[bytes] = []
            pub.on_subscribe = seen.append
            sub.subscribe(b"/y\0")
            assert pub.wait_for_subscriber("/y", timeout=10.0)
            assert b"/y\0" in seen


def test_a_synced_newcomer_loses_nothing_and_probes_stay_inside(bus_url: str) -> None:
    """Contract 9: twenty publishers, each publishing once as soon as ``sync`` returned, reach
    the subscribers that were there first (one to the topic, one to everything); the probes
    reach neither, nor anyone's ``on_subscribe``."""
    with open_transport(bus_url) as one, open_transport(bus_url) as every, \
            open_transport(bus_url) as old:
        one.subscribe(b"/x\0")
        every.subscribe(b"")
        assert old.wait_for_subscriber("/x", timeout=10.0)
        assert old.wait_for_subscriber("/anything", timeout=10.0)
        seen: list[bytes] = []
        old.on_subscribe = seen.append
        for i in range(20):
            with open_transport(bus_url) as pub:
                assert pub.sync(timeout=10.0)
                pub.publish(_clock("/x", i))
        old.service(0.05)
        for sub in (one, every):
            got = [sub.recv(timeout=10.0) for _ in range(20)]
            assert [decode(f).header.stamp_ns for f in got if f is not None] == [
                i * 10 for i in range(20)]
            assert sub.recv(timeout=0.1) is None
        assert seen == []


def test_a_synced_subscriber_gets_what_a_publisher_synced_after_it_sends(bus_url: str) -> None:
    """Contract 9, the subscribing side: twenty subscribers, each synced once subscribed, get
    the one message a publisher connected long before sends as soon as it synced in turn."""
    with open_transport(bus_url) as pub:
        assert pub.sync(timeout=10.0)
        for i in range(20):
            with open_transport(bus_url) as sub:
                sub.subscribe(b"/y\0")
                sub.subscribe(b"/z\0", lane=b"other")
                assert sub.sync(timeout=10.0) and pub.sync(timeout=10.0)
                pub.publish(_clock("/z", i))
                got = sub.recv(timeout=10.0)
                assert got is not None and decode(got).header.stamp_ns == i * 10


def test_sync_open_syncs_every_open_transport_of_the_process(bus_url: str) -> None:
    from hil_bridge.bus.transport import sync_open

    with open_transport(bus_url) as a, open_transport(bus_url):
        assert sync_open(10.0) == []
        a.close()
        assert sync_open(10.0) == []


def test_close_is_idempotent_and_later_use_raises(bus_url: str) -> None:
    t = open_transport(bus_url)
    t.close()
    t.close()
    assert t.closed
    with pytest.raises(TransportClosed):
        t.publish(_clock("/a", 0))
    with pytest.raises(TransportClosed):
        t.recv(timeout=0)
    with pytest.raises(TransportClosed):
        t.subscribe(b"/a\0")
    with open_transport(bus_url) as other, pytest.raises(ValueError, match="3 frames"):
        other.publish([b"/a\0"])


def test_iteration_yields_messages(bus_url: str) -> None:
    with open_transport(bus_url) as pub, open_transport(bus_url) as sub:
        sub.subscribe(b"")
        assert pub.wait_for_subscriber("/i", timeout=10.0)
        pub.publish(_clock("/i", 0))
        for frames in sub:
            assert frames[0] == b"/i\0"
            break


def test_unknown_scheme_lists_known_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown bus URL scheme 'udp'.*'mem'.*'tcp'"):
        open_transport("udp://1.2.3.4:5")
    assert set(BACKENDS) >= {"mem", "tcp", "ipc"}


@pytest.mark.parametrize(
    ("url", "pub", "sub"),
    [
        ("tcp://127.0.0.1:7400", "tcp://127.0.0.1:7400", "tcp://127.0.0.1:7401"),
        ("tcp://h:1?sub=tcp://g:9", "tcp://h:1", "tcp://g:9"),
        ("ipc:///tmp/bus", "ipc:///tmp/bus", "ipc:///tmp/bus.sub"),
    ],
)
def test_one_url_names_both_proxy_endpoints(url: str, pub: str, sub: str) -> None:
    ends = parse_zmq_url(url)
    assert (ends.pub, ends.sub) == (pub, sub)


@pytest.mark.parametrize(
    "url",
    ["tcp://h:1?hwm=0", "tcp://h:1?bogus=1", "tcp://h", "tcp://h:1?curve_server=x", "mem://"],
)
def test_bad_urls_name_the_problem(url: str) -> None:
    with pytest.raises(ValueError):
        open_transport(url)


def test_ipc_bus_and_proxy_for(tmp_path: object) -> None:
    assert proxy_for("mem://x") is None
    url = f"ipc://{tmp_path}/bus"
    proxy = proxy_for(url)
    assert isinstance(proxy, Proxy)
    with proxy, open_transport(url) as pub, open_transport(url) as sub:
        sub.subscribe(b"/p\0")
        assert pub.wait_for_subscriber("/p", timeout=10.0)
        pub.publish(_clock("/p", 3))
        frames = sub.recv(timeout=10.0)
        assert frames is not None and decode(frames).header.seq == 3
    proxy.stop()
    assert not proxy.running


@given(
    host=st.sampled_from(["127.0.0.1", "localhost", "10.0.0.7", "[::1]", "bus.lan"]),
    port=st.integers(1, 65534),
    sub_port=st.none() | st.integers(1, 65535),
    hwm=st.none() | st.integers(1, 10**6),
)
def test_zmq_url_parsing_properties(
    host: str, port: int, sub_port: int | None, hwm: int | None
) -> None:
    query = []
    if sub_port is not None:
        query.append(f"sub=tcp://{host}:{sub_port}")
    if hwm is not None:
        query.append(f"hwm={hwm}")
    url = f"tcp://{host}:{port}" + ("?" + "&".join(query) if query else "")
    ends = parse_zmq_url(url)
    assert ends.pub == f"tcp://{host}:{port}"
    assert ends.sub == f"tcp://{host}:{port + 1 if sub_port is None else sub_port}"
    assert ends.hwm == (1000 if hwm is None else hwm)


def test_publish_from_many_threads_loses_and_reorders_nothing(bus_url: str) -> None:
    n_threads, per_thread = 4, 200
    with open_transport(bus_url) as pub, open_transport(bus_url) as sub:
        sub.subscribe(b"/m\0")
        assert pub.wait_for_subscriber("/m", timeout=10.0)

        def send(k: int) -> None:
            for i in range(per_thread):
                pub.publish(encode("/m", Clock(stamp_ns=i), seq=i, pub_ns=0, src=f"t{k}"))

        threads = [threading.Thread(target=send, args=(k,)) for k in range(n_threads)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        per_src: dict[str, list[int]] = {}
        for _ in range(n_threads * per_thread):
            frames = sub.recv(timeout=10.0)
            assert frames is not None
            h = decode(frames).header
            per_src.setdefault(h.src, []).append(h.seq)
        assert per_src == {f"t{k}": list(range(per_thread)) for k in range(n_threads)}


def test_sync_gives_up_once_the_process_is_asked_to_stop(monkeypatch: pytest.MonkeyPatch) -> None:
    """Contract 9: a node host whose launcher died (the launch's proxy with it) is asked to stop
    (hil_bridge.lifetime.request_stop); its endpoints' syncs then end at once, not after their
    timeout (the host's is 30 s, beyond its 20 s of grace)."""
    with open_bus("zmq") as url, open_transport(url) as pub:
        assert pub.sync(timeout=10.0)
        monkeypatch.setattr(lifetime, "_STOPPING", lifetime.StopFlag())
        lifetime.request_stop()
        assert not pub.sync(timeout=10.0)  # the proxy is there: only the stop says no
