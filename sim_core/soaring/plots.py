"""PNG figures in the style of seed 002: paths (Figs 3–4), agent time series (Figs 7, 9, 10),
survival histograms split by a parameter (Figs 11–14) and mean-metric trends.

Matplotlib with the Agg backend; every function writes one PNG and returns its path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection
from mpl_toolkits.mplot3d.art3d import Line3DCollection  # type: ignore[import-untyped]
from numpy.typing import NDArray

from sim_core.soaring.trace import Trace

__all__ = ["plot_agent_series", "plot_paths", "plot_survival_histograms", "plot_trends"]


def _segments(trace: Trace, max_points: int) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """Path segments (M, 2, 3) of alive gliders, their time and vertical speed (M,)."""
    stride = max(1, trace.n_steps // max_points)
    sl = slice(0, None, stride)
    p = np.stack([trace.x[sl], trace.y[sl], trace.z[sl]], axis=-1)  # (S, N, 3)
    t = trace.t[sl]
    alive = trace.alive[sl]
    segs = np.stack([p[:-1], p[1:]], axis=2)  # (S-1, N, 2, 3)
    keep = alive[1:] & alive[:-1]
    tt = np.broadcast_to(t[1:, None], keep.shape)
    vz = trace.vz[sl][1:]
    return segs[keep], tt[keep], vz[keep]



def _save(fig: Any, path: str | Path) -> Path:
    """Lay out, write ``fig`` as a PNG at ``path`` and release it."""
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out

def plot_paths(trace: Trace, path: str | Path, *, max_points: int = 1500) -> Path:
    """All glider paths, coloured by time (top row, Fig 3) and by vertical speed (bottom row,
    Fig 4), seen from an upper corner, a side corner and from above."""
    segs, t, vz = _segments(trace, max_points)
    fig = plt.figure(figsize=(15, 9.5))
    lim = float(np.nanmax(np.abs(vz))) if vz.size else 1.0
    for row, (vals, cmap, label, norm) in enumerate((
        (t, "viridis", "time [s]", plt.Normalize(0, max(1.0, float(trace.t[-1])))),
        (vz, "coolwarm", "vertical speed [m/s]", plt.Normalize(-lim, lim)),
    )):
        for col, view in enumerate(((30, -60), (5, -30), None)):
            idx = row * 3 + col + 1
            if view is None:
                ax2 = fig.add_subplot(2, 3, idx)
                lc = LineCollection(list(segs[:, :, :2]), cmap=cmap, norm=norm, linewidths=0.5,
                                    alpha=0.6)
                lc.set_array(vals)
                ax2.add_collection(lc)
                ax2.autoscale()
                ax2.set_aspect("equal")
                ax2.set_xlabel("x [m]")
                ax2.set_ylabel("y [m]")
                mappable: Any = lc
                ax_for_bar: Any = ax2
            else:
                ax3: Any = fig.add_subplot(2, 3, idx, projection="3d")
                lc3 = Line3DCollection(segs, cmap=cmap, norm=norm, linewidths=0.4, alpha=0.5)
                lc3.set_array(vals)
                ax3.add_collection3d(lc3)
                if segs.size:
                    ax3.set_xlim(segs[..., 0].min(), segs[..., 0].max())
                    ax3.set_ylim(segs[..., 1].min(), segs[..., 1].max())
                    ax3.set_zlim(0, segs[..., 2].max())
                ax3.view_init(*view)
                ax3.set_xlabel("x [m]")
                ax3.set_ylabel("y [m]")
                ax3.set_zlabel("z [m]")
                mappable = lc3
                ax_for_bar = ax3
            if col == 2:
                fig.colorbar(mappable, ax=ax_for_bar, label=label, shrink=0.8)
    fig.suptitle(f"{trace.n_agents} gliders, {trace.t[-1]:.0f} s")
    return _save(fig, path)


def plot_agent_series(
    trace: Trace,
    agents: Sequence[int],
    path: str | Path,
    *,
    t_range: tuple[float, float] | None = None,
) -> Path:
    """Altitude, vertical speed and cohesion magnitude vs time for chosen gliders
    (seed Figs 7, 9, 10)."""
    n = trace.n_agents
    bad = [a for a in agents if not 0 <= a < n]
    if bad:
        raise ValueError(f"agent ids {bad} out of range 0..{n - 1}")
    sel = np.ones(trace.n_steps, dtype=bool)
    if t_range is not None:
        sel = (trace.t >= t_range[0]) & (trace.t <= t_range[1])
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for a in agents:
        t = trace.t[sel]
        alive = trace.alive[sel, a]
        for ax, arr in zip(axes, (trace.z, trace.vz, trace.cohesion), strict=True):
            ax.plot(t[alive], arr[sel, a][alive], lw=1.0, label=f"agent {a}")
    axes[0].set_ylabel("height [m]")
    axes[1].set_ylabel("vertical speed [m/s]")
    axes[2].set_ylabel("cohesion magnitude")
    axes[2].set_xlabel("time [s]")
    axes[0].legend(fontsize=8, ncol=4)
    return _save(fig, path)


def plot_survival_histograms(
    rows: Sequence[Mapping[str, Any]],
    by: str,
    path: str | Path,
    *,
    metric: str = "survivingPercent",
    bins: int = 20,
) -> Path:
    """Histograms of ``metric`` over sweep rows, one panel per value of parameter ``by``,
    log count axis (seed Figs 11–14)."""
    if not rows:
        raise ValueError("no rows to plot")
    if by not in rows[0]:
        raise ValueError(f"column {by!r} not in the table; columns: {sorted(rows[0])}")
    values = sorted({r[by] for r in rows}, key=lambda v: (str(type(v)), v))
    fig, axes = plt.subplots(1, len(values), figsize=(3.2 * len(values) + 1, 3.4), sharey=True,
                             squeeze=False)
    edges = np.linspace(0, 100, bins + 1) if metric == "survivingPercent" else bins
    for ax, val in zip(axes[0], values, strict=True):
        data = np.array([float(r[metric]) for r in rows if r[by] == val and r[metric] is not None])
        ax.hist(data, bins=edges, color="tab:blue", edgecolor="white")
        ax.set_yscale("log")
        ax.set_title(f"{by} = {val}  (n={data.size})", fontsize=9)
        ax.set_xlabel(metric)
    axes[0][0].set_ylabel("runs")
    return _save(fig, path)


def plot_trends(
    rows: Sequence[Mapping[str, Any]],
    params: Sequence[str],
    path: str | Path,
    *,
    metric: str = "survivingPercent",
) -> Path:
    """Mean ± standard error of ``metric`` against each parameter in ``params``."""
    fig, axes = plt.subplots(1, len(params), figsize=(3.6 * len(params), 3.2), squeeze=False)
    for ax, p in zip(axes[0], params, strict=True):
        vals = sorted({r[p] for r in rows})
        means, errs = [], []
        for v in vals:
            d = np.array([float(r[metric]) for r in rows if r[p] == v])
            means.append(d.mean())
            errs.append(d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else 0.0)
        xs = np.arange(len(vals))
        ax.errorbar(xs, means, yerr=errs, marker="o", capsize=3)
        ax.set_xticks(xs, [f"{v:g}" if isinstance(v, float) else str(v) for v in vals])
        ax.set_xlabel(p)
        ax.set_ylabel(f"mean {metric}")
    return _save(fig, path)
