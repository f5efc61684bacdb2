"""Links: URL checking, loop:// round trip with byte-exact capture, reconnect after unplug."""

from __future__ import annotations

import itertools
import threading
from pathlib import Path

import pytest

from drivers.serial.framing import FrameDecoder, MsgType, frame_bytes
from drivers.serial.link import Link, check_url, open_link
from drivers.serial.ptyport import PtyPort


class Sink:
    """Collects bytes from a link's reader thread; wait on a condition, never sleep."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.cv = threading.Condition()

    def __call__(self, chunk: bytes) -> None:
        with self.cv:
            self.data += chunk
            self.cv.notify_all()

    def wait_len(self, n: int, timeout: float = 5.0) -> bool:
        with self.cv:
            return self.cv.wait_for(lambda: len(self.data) >= n, timeout)


def test_unknown_scheme_lists_the_known_ones() -> None:
    with pytest.raises(ValueError, match=r"'bogus' unknown.*loop.*sonarsim"):
        check_url("bogus://x")
    with pytest.raises(ValueError, match="device path"):
        check_url("")
    assert check_url("/dev/ttyUSB0") == "/dev/ttyUSB0"


def test_missing_device_raises_the_open_error(tmp_path: Path) -> None:
    with pytest.raises(OSError, match="could not open port"):
        open_link(str(tmp_path / "nope"), connect_timeout_s=0.3)


def test_loop_round_trip_with_byte_exact_capture(tmp_path: Path) -> None:
    sink = Sink()
    frames = [frame_bytes(MsgType.STATUS, i, i * 10, bytes(range(i % 7 * 30))) for i in range(40)]
    wire = b"".join(frames)
    with open_link("loop://", on_bytes=sink, capture=tmp_path / "cap") as link:
        for f in frames:
            assert link.send(f)
        assert sink.wait_len(len(wire))
        assert link.stats()["bytes_tx"] == len(wire)
    dec = FrameDecoder()
    assert len(dec.feed(bytes(sink.data))) == 40 and dec.dropped == 0
    assert (tmp_path / "cap.tx.bin").read_bytes() == wire
    assert (tmp_path / "cap.rx.bin").read_bytes() == wire
    lines = (tmp_path / "cap.index.tsv").read_text().splitlines()
    assert lines[0].startswith("# echoloop serial capture v1 url=loop://")
    rows = [ln.split("\t") for ln in lines[2:]]
    assert [r[1] for r in rows if r[1] in ("open", "close")] == ["open", "close"]
    for kind in ("rx", "tx"):
        chunks = [(int(r[2]), int(r[3])) for r in rows if r[1] == kind]
        offsets = [o for o, _ in chunks]
        assert offsets == sorted(offsets) and offsets[0] == 0
        assert sum(n for _, n in chunks) == len(wire)
        assert all(o1 + n1 == o2 for (o1, n1), (o2, _) in itertools.pairwise(chunks))


def test_callback_error_is_counted_and_the_reader_survives() -> None:
    sink = Sink()
    calls = {"n": 0}

    def flaky(chunk: bytes) -> None:
        with sink.cv:
            calls["n"] += 1
            sink.cv.notify_all()
        if calls["n"] == 1:
            raise RuntimeError("subscriber bug")
        sink(chunk)

    with open_link("loop://", on_bytes=flaky) as link:
        link.send(b"first\x00")
        with sink.cv:
            assert sink.cv.wait_for(lambda: calls["n"] >= 1, 5.0)
        link.send(b"second\x00")
        assert sink.wait_len(7)
        assert link.callback_errors == 1


def test_unplug_then_replug_reconnects_under_the_same_path(tmp_path: Path) -> None:
    dev = PtyPort(tmp_path / "ttyFAKE")
    sink = Sink()
    link = Link(str(tmp_path / "ttyFAKE"), on_bytes=sink, backoff_initial_s=0.01,
                backoff_max_s=0.05, name="t")
    try:
        link.start()
        assert link.wait_connected(5.0)
        dev.write(b"before\x00")
        assert sink.wait_len(7)
        dev.unplug()
        assert link.wait_for(lambda lk: not lk.connected, 5.0)
        assert not link.send(b"lost")  # nothing is queued for a vanished port
        # a drop is a recoverable fault: no failure while the run goes, one if it ends now
        place = f"serial link {tmp_path / 'ttyFAKE'}"
        assert link.faults.failure() is None
        pending = link.faults.failure(final=True)  # what the OS said varies: the place does not
        assert pending is not None and pending.startswith(f"{place}: ")
        assert pending.endswith("(declared recoverable, never recovered)")
        dev.replug()
        assert link.wait_for(lambda lk: lk.connected and lk.reconnects == 1, 5.0)
        assert link.faults.failure(final=True) is None  # recovered by the re-open
        dev.write(b"after\x00")
        assert sink.wait_len(13)
        assert bytes(sink.data) == b"before\x00after\x00"
        assert link.read_errors == 1 and link.tx_dropped_bytes == 4
        assert link.faults.counts() == {place: 1}
    finally:
        link.stop()
        dev.close()
    link.stop()  # idempotent


def test_socket_url_round_trip_and_reconnect_after_the_peer_drops() -> None:
    """socket://: a TCP 'device' that echoes bytes, closes the first connection, accepts again."""
    import socket

    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(5.0)
    port = server.getsockname()[1]

    def device() -> None:
        for round_ in range(2):
            conn, _ = server.accept()
            with conn:
                conn.settimeout(5.0)
                data = conn.recv(64)
                conn.sendall(data.upper())
                if round_ == 0:
                    conn.shutdown(socket.SHUT_RDWR)

    t = threading.Thread(target=device, daemon=True)
    t.start()
    sink = Sink()
    link = open_link(f"socket://127.0.0.1:{port}", on_bytes=sink, backoff_initial_s=0.01,
                     backoff_max_s=0.05)
    try:
        link.send(b"ping\x00")
        assert sink.wait_len(5)
        assert link.wait_for(lambda lk: lk.connected and lk.reconnects == 1, 5.0)
        link.send(b"again\x00")
        assert sink.wait_len(11)
    finally:
        link.stop()
        t.join(5.0)
        server.close()
    assert bytes(sink.data) == b"PING\x00AGAIN\x00"


def test_pty_link_never_replaces_a_real_file(tmp_path: Path) -> None:
    precious = tmp_path / "ttyUSB0"
    precious.write_text("not a symlink")
    with pytest.raises(ValueError, match="not a symlink"):
        PtyPort(precious)
    assert precious.read_text() == "not a symlink"
    stale = tmp_path / "stale"
    stale.symlink_to(tmp_path / "gone")  # left by a crashed run: replaced
    port = PtyPort(stale)
    try:
        assert Path(str(stale)).resolve() == Path(port.path).resolve()
    finally:
        port.close()
    assert not stale.exists() and not stale.is_symlink()
