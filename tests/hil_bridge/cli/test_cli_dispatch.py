"""The echoloop dispatcher: usage, unknown commands, one-line user errors."""

from __future__ import annotations

import subprocess
import sys
import types

import pytest

from hil_bridge import cli


def test_usage_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert f"  {name}" in out


def test_no_args_is_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([]) == 2


def test_unknown_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["frobnicate"]) == 2
    assert "unknown command 'frobnicate'" in capsys.readouterr().err


def test_user_error_is_one_line(monkeypatch: pytest.MonkeyPatch,
                                capsys: pytest.CaptureFixture[str]) -> None:
    def boom(argv: list[str]) -> int:
        raise ValueError(f"bad value {argv[0]!r}")

    fake = types.ModuleType("fake_cmd")
    fake.main = boom  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "fake_cmd", fake)
    monkeypatch.setitem(cli.COMMANDS, "fake", ("fake_cmd", "a fake"))
    assert cli.main(["fake", "x"]) == 1
    err = capsys.readouterr().err
    assert err == "echoloop fake: error: bad value 'x'\n"


def test_every_command_module_imports() -> None:
    for name, (module, _) in cli.COMMANDS.items():
        proc = subprocess.run(
            [sys.executable, "-m", "hil_bridge.cli", name, "--help"],
            capture_output=True, text=True, timeout=120,
        )
        assert proc.returncode == 0, f"{name} ({module}): {proc.stderr[-500:]}"


def test_version_prints_the_distribution_version(capsys: pytest.CaptureFixture[str]) -> None:
    from importlib.metadata import version

    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out == f"echoloop {version('echoloop')}\n"
