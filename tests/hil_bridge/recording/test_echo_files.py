"""``echoloop echo --out`` writes .npz, .mat (read by scipy) and .wav (read by ``wave``), and the
opt-in physics options reach the model."""

from __future__ import annotations

import json
import struct
import wave
from pathlib import Path

import numpy as np
import pytest
from scipy.io import loadmat, wavfile

from hil_bridge.cli import main as echoloop
from sim_core.sonar import Beam, Call, Ear, EchoParams, synthesize
from tests.sim_core.sonar._scenes import cone_cloud

BASE = ["--position", "0,0,0", "--boresight", "0,0", "--beamwidth", "30", "--fidelity",
        "reference", "--samples", "4000"]
SHORT = EchoParams(samples=4000)


@pytest.fixture
def leaves(tmp_path: Path) -> Path:
    c, n, a = cone_cloud(60, seed=2, r_lo=0.5, r_hi=1.4)
    path = tmp_path / "leaves.npz"
    np.savez(path, centers=c, normals=n, radii=a)
    return path


def _reference(leaves: Path, params: EchoParams = SHORT) -> np.ndarray:
    with np.load(leaves) as d:
        c, n, a = d["centers"], d["normals"], d["radii"]
    return synthesize((c, n, a), Beam([0, 0, 0], [1, 0, 0], np.radians(30)), params,
                      fidelity="reference").samples


def _run(leaves: Path, *extra: str) -> None:
    assert echoloop(["echo", "--leaves", str(leaves), *BASE, *extra, "--json"]) == 0


def test_mat_holds_echo_fs_and_the_ping(leaves: Path, tmp_path: Path) -> None:
    out = tmp_path / "echo.mat"
    _run(leaves, "--out", str(out))
    m = loadmat(out, squeeze_me=False)
    assert m["echo"].shape == (4000, 1)  # one column per channel, MATLAB's layout
    np.testing.assert_allclose(m["echo"][:, 0], _reference(leaves), rtol=0, atol=1e-15)
    assert float(m["fs"][0, 0]) == 400e3
    ping = m["ping"][0, 0]
    assert float(ping["beamwidth_deg"][0, 0]) == 30.0
    assert str(ping["fidelity"][0]) == "reference"
    np.testing.assert_allclose(ping["position"].ravel(), [0.0, 0.0, 0.0])
    assert str(ping["call"][0]) == "none"


def test_wav_int16_is_read_by_the_wave_module(leaves: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "echo.wav"
    rc = echoloop(["echo", "--leaves", str(leaves), *BASE, "--out", str(out), "--wav-format",
                   "int16", "--json"])
    assert rc == 0
    full = json.loads(capsys.readouterr().out)["out_full_scale"]
    with wave.open(str(out), "rb") as w:
        assert (w.getnchannels(), w.getsampwidth(), w.getframerate()) == (1, 2, 400000)
        frames = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")
    ref = _reference(leaves)
    assert full == pytest.approx(np.abs(ref).max(), rel=1e-12)
    np.testing.assert_allclose(frames / 32767.0 * full, ref, atol=full / 32767.0)


def test_wav_float32_stereo_for_two_ears(leaves: Path, tmp_path: Path) -> None:
    out = tmp_path / "ears.wav"
    _run(leaves, "--ears", "0.04,10", "--out", str(out))
    raw = out.read_bytes()
    assert raw[:4] == b"RIFF" and raw[8:12] == b"WAVE"
    fmt = raw.index(b"fmt ")
    tag, channels, rate, _, _, bits = struct.unpack("<HHIIHH", raw[fmt + 8:fmt + 24])
    assert (tag, channels, rate, bits) == (3, 2, 400000, 32)  # IEEE float
    rate, data = wavfile.read(out)
    ears = EchoParams(samples=4000, ears=Ear.binaural(0.04, np.radians(10)))
    ref = _reference(leaves, ears)
    assert data.dtype == np.float32 and data.shape == (4000, 2)
    np.testing.assert_allclose(data.T, ref.astype(np.float32), rtol=0, atol=0)


def test_physics_options_reach_the_model(leaves: Path, tmp_path: Path) -> None:
    out = tmp_path / "phys.npz"
    _run(leaves, "--absorption", "--temperature", "30", "--humidity", "70", "--call", "fm",
         "--call-ms", "1", "--velocity", "-2,0.5,0", "--out", str(out))
    params = EchoParams(samples=4000, absorption=True, temperature_c=30.0, humidity_pct=70.0,
                        call=Call(kind="fm", duration_s=1e-3),
                        platform_velocity=(-2.0, 0.5, 0.0))
    with np.load(out) as d:
        np.testing.assert_allclose(d["echo"], _reference(leaves, params), rtol=0, atol=1e-15)
        assert bool(d["absorption"]) and float(d["humidity_pct"]) == 70.0
        np.testing.assert_allclose(d["platform_velocity"], [-2.0, 0.5, 0.0])
    assert not np.allclose(_reference(leaves, params), _reference(leaves))


def test_other_extensions_and_existing_files_are_refused_before_any_work(
    leaves: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def fails(*extra: str) -> str:
        assert echoloop(["echo", "--leaves", str(leaves), *BASE, *extra]) == 1
        return capsys.readouterr().err

    err = fails("--out", str(tmp_path / "echo.txt"))
    assert "echo.txt: unknown echo file extension '.txt'; expected one of ['.npz', '.mat', " \
           "'.wav']" in err
    assert not (tmp_path / "echo.txt").exists() and not (tmp_path / "echo.txt.npz").exists()
    out = tmp_path / "e.mat"
    out.write_bytes(b"keep")
    assert "e.mat: exists; pass --overwrite" in fails("--out", str(out))
    assert out.read_bytes() == b"keep"
    _run(leaves, "--out", str(out), "--overwrite")
    assert loadmat(out)["echo"].shape == (4000, 1)
    assert "--doppler needs --velocity" in fails("--doppler")
    assert "--ears: expected 1 or 2" in fails("--ears", "a,b")


def test_echo_plot_with_spectrogram(leaves: Path, tmp_path: Path) -> None:
    png = tmp_path / "echo.png"
    _run(leaves, "--plot", str(png), "--spectrogram", "--ears", "0.03")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
