"""Domains (ECHOLOOP_DOMAIN): disjoint names per domain, precedence, busy detection, CLI flag."""

from __future__ import annotations

import itertools
import os
import socket
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil_bridge.bus import domain as dm
from hil_bridge.bus.domain import (
    DOMAIN_ENV,
    MAX_DOMAIN,
    Domain,
    claim_first_free,
    current,
    first_free,
    resolve,
    use,
)
from hil_bridge.bus.transport.zmq import parse_zmq_url
from hil_bridge.cli import main as echoloop


def _names(d: Domain) -> set[str]:
    ends = parse_zmq_url(d.bus_url)
    return {ends.pub, ends.sub, f"live:{d.live_port}", str(d.path("sonar0")),
            d.can_channel("glider"), *(f"port:{p}" for p in (*d.ports, d.live_port))}


@given(st.integers(0, MAX_DOMAIN), st.integers(0, MAX_DOMAIN))
def test_two_domains_share_no_name(a: int, b: int) -> None:
    da, db = Domain(a), Domain(b)
    if a == b:
        assert _names(da) == _names(db)
    else:
        assert not _names(da) & _names(db)


def test_domain_zero_keeps_the_spec_defaults() -> None:
    d = Domain(0)
    assert d.bus_url == "tcp://127.0.0.1:7400"
    assert parse_zmq_url(d.bus_url).sub == "tcp://127.0.0.1:7401"
    assert d.live_port == 8765
    assert Domain(3).bus_url == "tcp://127.0.0.1:7430" and Domain(3).live_port == 8795
    assert max(Domain(MAX_DOMAIN).ports) < 8765 <= Domain(MAX_DOMAIN).live_port < 65536


@pytest.mark.parametrize("bad", [-1, MAX_DOMAIN + 1, True, 1.5, "3"])
def test_bad_domain_numbers_are_refused(bad: object) -> None:
    with pytest.raises(ValueError, match="domain"):
        Domain(bad)  # type: ignore[arg-type]


def test_precedence_explicit_then_active_then_env_then_zero(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv(DOMAIN_ENV, raising=False)
    token = dm._ACTIVE.set(None)  # step out of the suite's private domain
    try:
        assert current() == Domain(0)
        monkeypatch.setenv(DOMAIN_ENV, "7")
        assert current() == Domain(7)
        with use(Domain(9)):
            assert current() == Domain(9)
            assert resolve(4) == Domain(4) and resolve("5") == Domain(5)
        assert current() == Domain(7)
        monkeypatch.setenv(DOMAIN_ENV, "seven")
        with pytest.raises(ValueError, match=r"ECHOLOOP_DOMAIN='seven': expected an integer"):
            current()
    finally:
        dm._ACTIVE.reset(token)


def test_private_domains_are_in_process_and_unique(tmp_path: Path) -> None:
    a, b = Domain.private(tmp_path / "a"), Domain.private(tmp_path / "b")
    assert a.bus_url.startswith("mem://") and a.bus_url != b.bus_url
    assert a.can_channel() != b.can_channel() and a.live_port == 0 and a.ports == ()
    assert a.path("sonar0") == tmp_path / "a" / "sonar0"
    assert (tmp_path / "a").stat().st_mode & 0o777 == 0o700


def test_runtime_root_is_private_to_the_user() -> None:
    root = dm.runtime_root()
    assert root.stat().st_mode & 0o077 == 0
    assert Domain(12).dir() == root / "12"


def test_a_domain_with_a_bound_port_is_busy_and_auto_skips_it() -> None:
    for number in itertools.count(40):
        start = Domain(number)
        if start.busy_reason() is None and Domain(number + 1).busy_reason() is None:
            break
    with socket.socket() as squatter:
        squatter.bind(("127.0.0.1", start.ports[1]))
        squatter.listen()
        assert "in use" in str(start.busy_reason())
        chosen, skipped = first_free(start)
    assert chosen == Domain(number + 1)
    assert [d for d, _ in skipped] == [start]


def _free_from(number: int) -> Domain:
    found, _ = first_free(Domain(number))
    return found


def test_a_running_claim_makes_a_domain_busy_and_concurrent_autos_differ() -> None:
    """What --domain auto relies on: a run holds its domain from before anything binds."""
    start = _free_from(60)
    with start.claim():
        assert start.busy_reason() == "an echoloop run holds it"
        with start.claim():  # another run joining the same domain explicitly is fine
            pass
        with claim_first_free(start) as (first, skipped):
            assert first != start and [d for d, _ in skipped][:1] == [start]
            with claim_first_free(start) as (second, _):
                assert second not in (start, first)
    assert start.busy_reason() is None


def test_a_live_pty_link_makes_a_domain_busy(tmp_path: Path) -> None:
    from drivers.serial.ptyport import PtyPort

    d = Domain.private(tmp_path)
    port = PtyPort(d.path("sonar0"))
    try:
        assert "live pty" in str(d.busy_reason())
        with pytest.raises(ValueError, match="another process holds open"):
            PtyPort(d.path("sonar0"))
    finally:
        port.close()
    assert d.busy_reason() is None


def test_cli_domain_flag_reaches_the_defaults(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``echoloop topic list --domain N`` listens on domain N's bus; a bad value is one line."""
    monkeypatch.setenv(DOMAIN_ENV, "0")
    assert echoloop(["topic", "list", "--domain", "42", "--duration", "0.2"]) == 0
    assert "tcp://127.0.0.1:7820" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        echoloop(["topic", "list", "--domain", "100"])
    assert exc.value.code == 2
    assert "expected an integer 0..99" in capsys.readouterr().err


def test_a_link_left_by_a_killed_run_is_replaced_even_when_its_pty_number_is_reused(
    tmp_path: Path,
) -> None:
    """A link's target cannot tell a live run from a dead one (pty numbers are reused): a link
    that a killed run left behind, pointing at a pty another program now holds open, neither
    makes the domain busy nor stops the next mock from taking it."""
    from drivers.serial.ptyport import PtyPort

    d = Domain.private(tmp_path)
    other = PtyPort()  # another program's pty, open
    try:
        os.symlink(other.path, d.path("sonar0"))  # what a SIGKILLed mock leaves behind
        assert d.busy_reason() is None
        port = PtyPort(d.path("sonar0"))
        try:
            assert os.readlink(d.path("sonar0")) == port.path != other.path
        finally:
            port.close()
    finally:
        other.close()
