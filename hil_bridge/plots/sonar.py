"""Figures of the seed 000 sonar scenarios (matplotlib, Agg backend, PNG files).

* :func:`plot_fig6` — static sonar, one column per beamwidth: side view with the leaves inside
  the -3 dB contour in red, and the impulse response below (seed 000 Fig 6);
* :func:`plot_fig7` — bird's-eye view of the "8" route with each ping's -3 dB wedge and
  in-beam leaves in red, plus the 12 impulse responses (Fig 7);
* :func:`plot_table1` — Table 1 timings beside the seed's MATLAB numbers;
* :func:`plot_echo` — one echo: waveform, envelope in dB re the emitted amplitude, and
  optionally its spectrogram.

Amplitudes are relative to the emitted peak amplitude ``A0`` at 1 m (``EchoParams.peak_amplitude``,
spec: ``A0 = 1``), so levels in dB are "dB re A0".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import BinaryIO

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from sim_core.sonar.baseband import envelope_db
from sim_core.sonar.params import Echo, EchoParams
from sim_core.sonar.scenarios import TABLE1_SEED_SECONDS, Ping
from sim_core.world import Leaves

__all__ = ["in_contour", "plot_echo", "plot_fig6", "plot_fig7", "plot_table1"]

_MAX_POINTS = 30_000


def in_contour(leaves: Leaves, ping: Ping, params: EchoParams) -> NDArray[np.bool_]:
    """Leaves inside the -3 dB cone (off-axis angle <= BW/2) and kept by the selection, (M,)."""
    d = leaves.centers - ping.beam.position
    r = np.linalg.norm(d, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_t = (d @ ping.beam.boresight) / r
    theta = np.arccos(np.clip(cos_t, -1.0, 1.0))
    s1 = params.peak_amplitude * np.exp(-(theta**2) / (2.0 * ping.beam.sigma**2))
    return (theta <= 0.5 * ping.beam.beamwidth_rad) & (r <= params.selection_radius * s1) & (
        r >= params.r_min
    )


def _subsample(n: int) -> NDArray[np.intp]:
    return np.arange(0, n, max(1, n // _MAX_POINTS))


def _wedge(ax: plt.Axes, ping: Ping, params: EchoParams, dims: tuple[int, int]) -> None:
    """The -3 dB contour (cone edges out to the waterdrop range) projected on ``dims``."""
    b = ping.beam.boresight
    frame = ping.beam.frame()
    half = 0.5 * ping.beam.beamwidth_rad
    reach = params.selection_radius * 0.7079
    p = ping.beam.position
    for side in (frame[1], frame[2]):
        for sign in (-1.0, 1.0):
            edge = np.cos(half) * b + sign * np.sin(half) * side
            q = p + reach * edge
            ax.plot([p[dims[0]], q[dims[0]]], [p[dims[1]], q[dims[1]]], color="red", lw=0.8)
    ax.plot(p[dims[0]], p[dims[1]], "k^", ms=6)


def plot_fig6(
    leaves: Leaves, pings: Sequence[Ping], echoes: Sequence[Echo], params: EchoParams, path: Path
) -> None:
    """Side view (x-z) of the tree per beamwidth, -3 dB leaves red, waveform below."""
    fig, axes = plt.subplots(2, len(pings), figsize=(5 * len(pings), 8),
                             gridspec_kw={"height_ratios": [3, 1]}, squeeze=False)
    idx = _subsample(len(leaves))
    for col, (ping, echo) in enumerate(zip(pings, echoes, strict=True)):
        ax = axes[0, col]
        ax.scatter(leaves.centers[idx, 0], leaves.centers[idx, 2], s=0.3, c="tab:green",
                   alpha=0.4, lw=0)
        mask = in_contour(leaves, ping, params)
        ax.scatter(leaves.centers[mask, 0], leaves.centers[mask, 2], s=1.5, c="red", lw=0)
        _wedge(ax, ping, params, (0, 2))
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("z (m)")
        ax.set_title(f"{ping.label}: {int(mask.sum())} leaves in -3 dB, "
                     f"{echo.leaves_in_beam} in beam")
        wave = axes[1, col]
        wave.plot(echo.times * 1e3, echo.samples, lw=0.5, color="k")
        wave.set_xlabel("time since emission (ms)")
        wave.set_ylabel("amplitude (re A0)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_fig7(
    leaves: Leaves, pings: Sequence[Ping], echoes: Sequence[Echo], params: EchoParams, path: Path
) -> None:
    """Top view of the route with -3 dB wedges and in-beam leaves, and every impulse response."""
    fig = plt.figure(figsize=(16, 8))
    top = fig.add_axes((0.04, 0.08, 0.45, 0.86))
    idx = _subsample(len(leaves))
    top.scatter(leaves.centers[idx, 0], leaves.centers[idx, 1], s=0.3, c="tab:green",
                alpha=0.4, lw=0)
    route = np.array([p.beam.position for p in pings])
    top.plot(np.r_[route[:, 0], route[:1, 0]], np.r_[route[:, 1], route[:1, 1]], "k--", lw=0.6)
    for k, ping in enumerate(pings):
        mask = in_contour(leaves, ping, params)
        top.scatter(leaves.centers[mask, 0], leaves.centers[mask, 1], s=1.0, c="red", lw=0)
        _wedge(top, ping, params, (0, 1))
        px, py = float(ping.beam.position[0]), float(ping.beam.position[1])
        top.annotate(f"P{k + 1}", (px, py), fontsize=8,
                     xytext=(3, 3), textcoords="offset points")
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title('"8" route, -3 dB contours (red)')
    cols = 3
    rows = int(np.ceil(len(pings) / cols))
    for k, (ping, echo) in enumerate(zip(pings, echoes, strict=True)):
        r, c = divmod(k, cols)
        ax = fig.add_axes((0.53 + c * 0.155, 0.08 + (rows - 1 - r) * (0.86 / rows),
                           0.14, 0.86 / rows - 0.04))
        ax.plot(echo.times * 1e3, echo.samples, lw=0.4, color="k")
        ax.set_title(f"{ping.label} ({echo.leaves_in_beam} leaves)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("time (ms)", fontsize=6, labelpad=1)
        ax.set_ylabel("amplitude (re A0)", fontsize=6, labelpad=1)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_table1(measured: Mapping[str, Mapping[int, Sequence[float]]], label: str,
                path: Path) -> None:
    """Measured seconds (``measured[setup][factor][T-1]``) beside the seed's MATLAB seconds."""
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, setup, xlabel in ((axes[0], "circular", "positions on the circle"),
                              (axes[1], "fixed", "beamwidth (deg)")):
        factors = sorted(TABLE1_SEED_SECONDS[setup])
        for t in range(5):
            seed_s = [TABLE1_SEED_SECONDS[setup][f][t] for f in factors]
            ours = [measured[setup][f][t] for f in factors]
            color = plt.get_cmap("viridis")(t / 4)
            ax.plot(factors, seed_s, "--", color=color, label=f"seed MATLAB T={t + 1}")
            ax.plot(factors, ours, "-o", color=color, ms=3, label=f"{label} T={t + 1}")
        ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("seconds (total per setup cell)")
        ax.grid(True, which="both", alpha=0.3)
    axes[1].legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_echo(
    samples: NDArray[np.floating],
    fs: float,
    path: Path | BinaryIO,
    *,
    title: str = "",
    sound_speed: float = 340.0,
    spectrogram: bool = False,
    band: tuple[float, float] | None = None,
    dynamic_range_db: float = 80.0,
) -> None:
    """One echo, (N,) or (C, N) at ``fs`` Hz, t = 0 at emission: the waveform (re A0), its
    envelope in dB re A0 with the peak level marked, and with ``spectrogram`` the level over
    time and frequency (first channel; ``band`` (Hz) zooms it on the model band). The top
    axis gives the range ``c t / 2`` in metres.
    Levels more than ``dynamic_range_db`` below the peak are cut off."""
    x = np.atleast_2d(np.asarray(samples, dtype=np.float64))
    t_ms = np.arange(x.shape[-1]) / fs * 1e3
    env = envelope_db(x)
    peak_db = float(env.max())
    low = peak_db - dynamic_range_db
    names = [f"channel {c}" for c in range(x.shape[0])] if x.shape[0] > 1 else [None]
    rows = 3 if spectrogram else 2
    fig, axes = plt.subplots(rows, 1, figsize=(9.5, 2.6 * rows), sharex=True)
    wave, level = axes[0], axes[1]
    for c, row in enumerate(x):
        wave.plot(t_ms, row, lw=0.5, label=names[c])
        level.plot(t_ms, env[c], lw=0.7, label=names[c])
    wave.set_ylabel("amplitude (re A0)")
    wave.set_title(title)
    level.axhline(peak_db, color="0.4", ls="--", lw=0.8)
    level.annotate(f"peak {peak_db:.1f} dB re A0", (t_ms[-1], peak_db), ha="right",
                   va="bottom", fontsize=8, color="0.3")
    level.set_ylim(low, peak_db + 6.0)
    level.set_ylabel("envelope (dB re A0)")
    if x.shape[0] > 1:
        wave.legend(fontsize=7, loc="upper right")
    if spectrogram:
        from scipy.signal import spectrogram as stft

        nper = min(512, x.shape[-1])
        f, tt, sxx = stft(x[0], fs=fs, nperseg=nper, noverlap=nper * 3 // 4, mode="magnitude",
                          scaling="spectrum")
        with np.errstate(divide="ignore"):
            sdb = 20.0 * np.log10(np.maximum(sxx, 1e-300))
        top = float(sdb.max())
        mesh = axes[2].pcolormesh(tt * 1e3, f / 1e3, sdb, shading="auto", cmap="magma",
                                  vmin=top - dynamic_range_db, vmax=top)
        axes[2].set_ylabel("frequency (kHz)")
        if band is not None:
            width = band[1] - band[0]
            axes[2].set_ylim(max(0.0, band[0] - width) / 1e3, min(fs / 2, band[1] + width) / 1e3)
        fig.colorbar(mesh, cax=axes[2].inset_axes((1.01, 0.0, 0.015, 1.0)), label="dB re A0")
    axes[-1].set_xlabel("time since emission (ms)")
    rng = wave.secondary_xaxis(
        "top", functions=(lambda ms: ms * 1e-3 * sound_speed / 2.0,
                          lambda m: m * 2.0 / sound_speed * 1e3))
    rng.set_xlabel("range (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=120, format="png")
    plt.close(fig)
