"""Figures of the seed 000 sonar scenarios (matplotlib, Agg backend, PNG files).

* :func:`plot_fig6` — static sonar, one column per beamwidth: side view with the leaves inside
  the -3 dB contour in red, and the impulse response below (seed 000 Fig 6);
* :func:`plot_fig7` — bird's-eye view of the "8" route with each ping's -3 dB wedge and
  in-beam leaves in red, plus the 12 impulse responses (Fig 7);
* :func:`plot_table1` — Table 1 timings beside the seed's MATLAB numbers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from sim_core.sonar.params import Echo, EchoParams
from sim_core.sonar.scenarios import TABLE1_SEED_SECONDS, Ping
from sim_core.world import Leaves

__all__ = ["in_contour", "plot_fig6", "plot_fig7", "plot_table1"]

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
        wave.set_xlabel("time (ms)")
        wave.set_ylabel("impulse response")
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
        ax.set_title(f"{ping.label} ({echo.leaves_in_beam})", fontsize=7)
        ax.tick_params(labelsize=6)
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
