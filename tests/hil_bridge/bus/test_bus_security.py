"""Security: no off-loopback bind without CURVE; with CURVE a listed key talks, others are
rejected and counted."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import zmq.auth

from hil_bridge.bus.codec import decode, encode
from hil_bridge.bus.messages import Clock
from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.security import CurveKeys, generate_keys, is_loopback_endpoint
from hil_bridge.bus.transport import open_transport
from hil_bridge.errors import SecurityError


@pytest.mark.parametrize(
    "endpoint", ["tcp://0.0.0.0:7400", "tcp://*:7400", "tcp://10.1.2.3:7400", "tcp://host:1"]
)
def test_non_loopback_bind_without_keys_refuses_to_start(endpoint: str) -> None:
    with pytest.raises(SecurityError, match="refusing to bind"):
        Proxy(endpoint, "tcp://127.0.0.1:0")
    with pytest.raises(SecurityError):
        Proxy("tcp://127.0.0.1:0", endpoint)


def test_cli_bus_refuses_non_loopback_without_keys() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "hil_bridge.cli", "bus", "--pub", "tcp://0.0.0.0:0",
         "--sub", "tcp://0.0.0.0:0"],
        capture_output=True, text=True, timeout=60, check=False,
    )
    assert proc.returncode == 1
    assert "refusing to bind" in proc.stderr


@pytest.mark.parametrize(
    ("endpoint", "loopback"),
    [("tcp://127.0.0.1:1", True), ("tcp://localhost:1", True), ("tcp://[::1]:1", True),
     ("ipc:///tmp/x", True), ("tcp://192.168.1.2:1", False), ("tcp://0.0.0.0:1", False)],
)
def test_loopback_classification(endpoint: str, loopback: bool) -> None:
    assert is_loopback_endpoint(endpoint) is loopback


def test_curve_known_client_talks_unknown_client_is_rejected_and_counted(tmp_path: Path) -> None:
    keys = generate_keys(tmp_path / "keys", ["sim"])
    intruder_public, intruder_secret = zmq.auth.create_certificates(tmp_path, "intruder")
    Path(intruder_secret).chmod(0o600)  # the intruder keeps its own key private
    curve = CurveKeys.from_dir(keys)
    assert len(curve.allowed) == 1
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0", curve=curve) as proxy:
        server = f"curve_server={keys / 'server.key'}"
        good = f"{proxy.url}&{server}&curve_client={keys / 'sim.key_secret'}"
        bad = f"{proxy.url}&{server}&curve_client={tmp_path / 'intruder.key_secret'}"
        plain = proxy.url
        with open_transport(good) as pub, open_transport(good) as sub:
            sub.subscribe(b"/clock\0")
            assert pub.wait_for_subscriber("/clock", timeout=10.0)
            pub.publish(encode("/clock", Clock(stamp_ns=5), seq=0, pub_ns=0))
            frames = sub.recv(timeout=10.0)
            assert frames is not None and decode(frames).msg == Clock(stamp_ns=5)
        accepted = proxy.stats()["auth_accepted"]
        assert accepted >= 2
        with open_transport(bad) as intruder, open_transport(plain) as stranger:
            intruder.subscribe(b"/clock\0")
            stranger.subscribe(b"/clock\0")
            deadline = time.monotonic() + 10.0
            while proxy.stats()["auth_rejected"] < 2 and time.monotonic() < deadline:
                intruder.recv(timeout=0.01)  # drive the socket; nothing may arrive
            assert proxy.stats()["auth_rejected"] >= 2  # both intruder sockets rejected
            assert intruder_public and not intruder.has_subscriber("/clock")
            assert stranger.recv(timeout=0.05) is None
        assert proxy.stats()["auth_accepted"] == accepted
        assert proxy.allow_list is not None and len(proxy.allow_list.rejected_keys) == 1


def test_key_dir_errors_name_the_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"server\.key_secret"):
        CurveKeys.from_dir(tmp_path)
    _, secret = zmq.auth.create_certificates(tmp_path, "server")
    Path(secret).chmod(0o600)
    with pytest.raises(ValueError, match="authorized"):
        CurveKeys.from_dir(tmp_path)


def test_cli_bus_runs_a_proxy_until_sigterm() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "bus", "--pub", "tcp://127.0.0.1:0",
         "--sub", "tcp://127.0.0.1:0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        url = line.rsplit("clients use ", 1)[1].strip()
        with open_transport(url) as pub, open_transport(url) as sub:
            sub.subscribe(b"")
            assert pub.wait_for_subscriber("/clock", timeout=10.0)
            pub.publish(encode("/clock", Clock(stamp_ns=1), seq=0, pub_ns=0))
            assert sub.recv(timeout=10.0) is not None
    finally:
        proc.terminate()
        _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err


def test_keygen_writes_secret_keys_0600_and_never_replaces_keys(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from hil_bridge.cli import main as echoloop

    keys = tmp_path / "keys"
    assert echoloop(["bus", "--keygen", str(keys), "--clients", "sim,viewer"]) == 0
    modes = {p.relative_to(keys).as_posix(): p.stat().st_mode & 0o777
             for p in keys.rglob("*") if p.is_file()}
    assert {k: v for k, v in modes.items() if k.endswith("_secret")} == {
        "server.key_secret": 0o600, "sim.key_secret": 0o600, "viewer.key_secret": 0o600}
    assert keys.stat().st_mode & 0o077 == 0
    assert not [p for p in keys.rglob("*.part*")]
    before = (keys / "server.key_secret").read_bytes()
    assert echoloop(["bus", "--keygen", str(keys), "--clients", "sim"]) == 1
    assert "server.key: exists; pass --overwrite" in capsys.readouterr().err
    assert (keys / "server.key_secret").read_bytes() == before
    assert echoloop(["bus", "--keygen", str(keys), "--clients", "sim", "--overwrite"]) == 0
    assert (keys / "server.key_secret").read_bytes() != before
    assert CurveKeys.from_dir(keys).allowed  # what was written loads


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604])
def test_secret_keys_readable_by_others_are_refused(tmp_path: Path, mode: int) -> None:
    keys = generate_keys(tmp_path / "keys", ["sim"])
    (keys / "sim.key_secret").chmod(mode)
    url = (f"tcp://127.0.0.1:7999?curve_server={keys / 'server.key'}"
           f"&curve_client={keys / 'sim.key_secret'}")
    with pytest.raises(SecurityError, match=r"sim\.key_secret: secret key file is readable by "
                                            r"group or others .*chmod 600"):
        open_transport(url)
    (keys / "server.key_secret").chmod(mode)
    with pytest.raises(SecurityError, match=r"server\.key_secret: .*chmod 600"):
        CurveKeys.from_dir(keys)
