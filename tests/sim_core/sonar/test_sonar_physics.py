"""Opt-in physics switches, each measured against the reference and a closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from sim_core.sonar import Beam, Call, Ear, EchoParams, synthesize
from sim_core.sonar.physics import absorption_db_per_m, call_waveform, sound_speed_from_temperature
from tests.sim_core.sonar._scenes import FS, N, V, cone_cloud, envelope, rel_l2, single_leaf_peak

BEAM = Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], math.radians(30.0))
R0 = 7000 / FS * V / 2.0  # 2 r / v on sample 7000


def leaf(r: float = R0, a: float = 0.025, y: float = 0.0) -> tuple:
    return (np.array([[r, y, 0.0]]), np.array([[-1.0, 0.0, 0.0]]), np.array([a]))


def peak(params: EchoParams, leaves: tuple = leaf(), fidelity: str = "reference") -> float:
    return float(envelope(synthesize(leaves, BEAM, params, fidelity=fidelity).samples).max())


def test_iso9613_absorption_matches_published_values() -> None:
    # ISO 9613-1 Table 1 (20 degC, 70 % RH, 101.325 kPa): 1 kHz 4.99 dB/km, 4 kHz 22.9 dB/km
    got = absorption_db_per_m([1e3, 4e3], 20.0, 70.0, 101.325)
    np.testing.assert_allclose(got, [4.99e-3, 22.9e-3], rtol=0.01)
    # 60-80 kHz at 20 degC, 50 % RH: about 2 dB/m (spec research note)
    assert 1.5 < float(absorption_db_per_m(70e3, 20.0, 50.0, 101.325)) < 2.6


def test_absorption_off_is_reference_and_on_is_the_closed_form_attenuation() -> None:
    params = EchoParams(absorption=True, temperature_c=15.0, humidity_pct=30.0)
    assert peak(EchoParams(absorption=False)) == peak(EchoParams())

    def atten(f: np.ndarray) -> np.ndarray:
        return 10.0 ** (-absorption_db_per_m(f, 15.0, 30.0, 101.325) * 2 * R0 / 20.0)

    expected = single_leaf_peak(R0, 0.025, 0.0, factor=atten)
    assert peak(params) == pytest.approx(expected, rel=1e-9)
    assert peak(params, fidelity="fast") == pytest.approx(expected, rel=1e-3)


def test_sound_speed_from_temperature_moves_the_pulse() -> None:
    params = EchoParams(speed_from_temperature=True, temperature_c=0.0)
    v = sound_speed_from_temperature(0.0)
    assert v == pytest.approx(331.3)
    env = envelope(synthesize(leaf(), BEAM, params, fidelity="reference").samples)
    assert int(np.argmax(env)) == round(2 * R0 / v * FS)


def test_moving_platform_delay_is_two_r_over_v_plus_speed() -> None:
    speed = 10.0
    params = EchoParams(platform_velocity=(speed, 0.0, 0.0))
    for fid in ("reference", "fast"):
        env = envelope(synthesize(leaf(), BEAM, params, fidelity=fid).samples)
        assert int(np.argmax(env)) == round(2 * R0 / (V + speed) * FS)
    lateral = EchoParams(platform_velocity=(0.0, speed, 0.0))
    env = envelope(synthesize(leaf(), BEAM, lateral, fidelity="reference").samples)
    t1 = R0 / V  # then the receiver, moving along y, meets the echo when |q - V s| = v s
    s = brentq(lambda s: math.hypot(R0, speed * (t1 + s)) - V * s, 0.0, 1.0)
    assert abs(int(np.argmax(env)) - (t1 + s) * FS) <= 1.0


def test_doppler_scales_the_band_by_the_two_way_factor() -> None:
    speed = 10.0
    still = synthesize(leaf(), BEAM, EchoParams(), fidelity="reference").samples
    moving = synthesize(leaf(), BEAM, EchoParams(platform_velocity=(speed, 0.0, 0.0),
                                                 doppler=True), fidelity="reference").samples
    f = np.fft.rfftfreq(N, 1 / FS)

    def centroid(x: np.ndarray) -> float:
        p = np.abs(np.fft.rfft(x)) ** 2
        return float((f * p).sum() / p.sum())

    eta = (V + speed) / (V - speed)
    assert centroid(moving) / centroid(still) == pytest.approx(eta, rel=2e-3)
    assert int(np.argmax(envelope(moving))) == round(2 * R0 / (V + speed) * FS)


def test_call_echo_is_the_call_convolved_with_the_impulse_response() -> None:
    leaves = cone_cloud(200, seed=4, r_hi=7.0)
    h = synthesize(leaves, BEAM, EchoParams(), fidelity="reference").samples
    for call in (Call(kind="fm"), Call(kind="cf-fm", cf_hz=79e3, cf_duration_s=5e-3)):
        echo = synthesize(leaves, BEAM, EchoParams(call=call), fidelity="reference").samples
        s = call_waveform(call, FS)
        linear = np.convolve(h, s)[:N]
        assert rel_l2(echo, linear) < 1e-6
        fast = synthesize(leaves, BEAM, EchoParams(call=call), fidelity="fast").samples
        assert rel_l2(fast, echo) < 1e-3


def test_cf_fm_call_puts_energy_at_the_cf_when_the_band_holds_it() -> None:
    call = Call(kind="cf-fm", cf_hz=83e3, cf_duration_s=5e-3, f_end=65e3)
    params = EchoParams(call=call, f_hi=85e3)
    echo = synthesize(leaf(), BEAM, params, fidelity="reference").samples
    spec = np.abs(np.fft.rfft(echo))
    f = np.fft.rfftfreq(N, 1 / FS)
    assert abs(f[np.argmax(spec)] - 83e3) < 200.0


def test_shading_attenuates_a_leaf_hidden_behind_a_nearer_one() -> None:
    near, far = leaf(2.0, a=0.05), leaf(R0, a=0.02)
    both = tuple(np.concatenate([x, y]) for x, y in zip(near, far, strict=True))
    opacity = 0.6
    params = EchoParams(shading=True, shading_opacity=opacity)
    got = synthesize(both, BEAM, params, fidelity="reference").samples
    h_near = synthesize(near, BEAM, fidelity="reference").samples
    h_far = synthesize(far, BEAM, fidelity="reference").samples
    np.testing.assert_allclose(got, h_near + (1 - opacity) ** 2 * h_far, atol=1e-15)
    side = tuple(np.concatenate([x, y]) for x, y in zip(near, leaf(R0, 0.02, y=0.5), strict=True))
    unshaded = synthesize(side, BEAM, params, fidelity="reference").samples
    np.testing.assert_allclose(unshaded, synthesize(side, BEAM, fidelity="reference").samples)
    assert rel_l2(synthesize(both, BEAM, params).samples, got) < 1e-3


def test_near_field_cap_limits_a_leaf_to_a_mirror() -> None:
    r = 400 / FS * V / 2.0  # 0.17 m
    big = leaf(r, a=0.1)
    capped = peak(EchoParams(near_field_cap=True), big)
    assert capped == pytest.approx(single_leaf_peak(r, 0.1, 0.0, cap=r / 2), rel=1e-9)
    assert capped < peak(EchoParams(), big)
    assert peak(EchoParams(near_field_cap=True), big, "fast") == pytest.approx(capped, rel=1e-3)
    assert peak(EchoParams(near_field_cap=True)) == peak(EchoParams())  # far leaf: no cap


def test_binaural_ears_give_two_channels_with_their_own_delays() -> None:
    spacing = 0.2
    params = EchoParams(ears=Ear.binaural(spacing_m=spacing, splay_rad=0.0))
    echo = synthesize(leaf(), BEAM, params, fidelity="reference")
    assert echo.samples.shape == (2, N)
    path = R0 + math.hypot(R0, spacing / 2)
    for ch in range(2):
        assert abs(int(np.argmax(envelope(echo.samples[ch]))) - path / V * FS) <= 1.0
    np.testing.assert_allclose(echo.samples[0], echo.samples[1], atol=1e-12)
    colocated = EchoParams(ears=(Ear(),))
    mono = synthesize(leaf(), BEAM, fidelity="reference").samples
    np.testing.assert_allclose(synthesize(leaf(), BEAM, colocated, fidelity="reference")
                               .samples[0], mono, atol=1e-15)
    splayed = EchoParams(ears=Ear.binaural(spacing_m=0.02, splay_rad=math.radians(20)))
    off = synthesize(leaf(R0, y=1.0), BEAM, splayed, fidelity="reference").samples
    assert envelope(off[0]).max() > envelope(off[1]).max()  # leaf on the left (+y)
    fast = synthesize(cone_cloud(300, seed=8), BEAM, splayed, fidelity="fast").samples
    ref = synthesize(cone_cloud(300, seed=8), BEAM, splayed, fidelity="reference").samples
    assert fast.shape == (2, N) and rel_l2(fast, ref) < 1e-3


def test_seed2020_parity_has_no_spreading_and_an_az_el_beam() -> None:
    parity = EchoParams(seed2020=True)
    assert peak(parity, leaf(R0)) == pytest.approx(peak(parity, leaf(2 * R0 * 0.7)), rel=1e-9)
    el0 = math.radians(60.0)
    beam = Beam.from_az_el([0, 0, 0], 0.0, el0, math.radians(40.0))
    daz = math.radians(10.0)
    u = np.array([math.cos(el0) * math.cos(daz), math.cos(el0) * math.sin(daz), math.sin(el0)])
    one = (u[None] * R0, -u[None], np.array([0.025]))
    got = envelope(synthesize(one, beam, parity, fidelity="reference").samples).max()
    s1 = math.exp(-(daz**2) / (2 * beam.sigma**2))
    assert got == pytest.approx(single_leaf_peak(R0, 0.025, 0.0, spreading=False,
                                                 gain=s1**2), rel=1e-9)
    gc = math.acos(float(u @ beam.boresight))
    spec_peak = envelope(synthesize(one, beam, EchoParams(spreading=False),
                                    fidelity="reference").samples).max()
    s1_gc = math.exp(-(gc**2) / (2 * beam.sigma**2))
    assert spec_peak == pytest.approx(single_leaf_peak(R0, 0.025, 0.0, spreading=False,
                                                       gain=s1_gc**2), rel=1e-9)


def test_incident_freq_beamwidth_follows_the_seed_polynomial() -> None:
    params = EchoParams(beam_model="incident_freq")
    assert peak(params) == pytest.approx(peak(EchoParams()), rel=1e-12)  # on axis S = 1
    off = math.radians(10.0)
    one = (np.array([[R0 * math.cos(off), R0 * math.sin(off), 0.0]]),
           np.array([[-math.cos(off), -math.sin(off), 0.0]]), np.array([0.025]))

    def gain(f: np.ndarray) -> np.ndarray:
        fk = f / 1e3
        bw = np.radians(0.011333 * fk**3 - 2.3219 * fk**2 + 156.15 * fk - 3402.7)
        sigma = bw / 2 / math.sqrt(2 * math.log(1 / 0.7079))
        return np.exp(-(off**2) / (2 * sigma**2)) ** 2

    got = envelope(synthesize(one, BEAM, params, fidelity="reference").samples)[7000]
    assert got == pytest.approx(single_leaf_peak(R0, 0.025, 0.0, factor=gain), rel=1e-9)
    fast = envelope(synthesize(one, BEAM, params, fidelity="fast").samples)[7000]
    assert fast == pytest.approx(got, rel=1e-3)
