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
from matplotlib.ticker import MaxNLocator
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
    Fig 4): a 3-D view from an upper corner, a side view (x–z) and the top view (x–y).
    Horizontal distances are in km once the swarm spans more than 2 km."""
    segs, t, vz = _segments(trace, max_points)
    span = float(np.ptp(segs[..., :2])) if segs.size else 0.0
    scale, unit = (1e-3, "km") if span > 2000.0 else (1.0, "m")
    xy = segs.copy()
    xy[..., :2] *= scale
    fig = plt.figure(figsize=(16, 9.5))
    lim = float(np.nanmax(np.abs(vz))) if vz.size else 1.0
    for row, (vals, cmap, label, norm) in enumerate((
        (t, "viridis", "time (s)", plt.Normalize(0, max(1.0, float(trace.t[-1])))),
        (vz, "coolwarm", "vertical speed (m/s)", plt.Normalize(-lim, lim)),
    )):
        ax3: Any = fig.add_subplot(2, 3, row * 3 + 1, projection="3d")
        lc3 = Line3DCollection(xy, cmap=cmap, norm=norm, linewidths=0.4, alpha=0.6)
        lc3.set_array(vals)
        ax3.add_collection3d(lc3)
        if xy.size:
            ax3.set_xlim(xy[..., 0].min(), xy[..., 0].max())
            ax3.set_ylim(xy[..., 1].min(), xy[..., 1].max())
            ax3.set_zlim(0, xy[..., 2].max())
        ax3.view_init(30, -60)
        for axis in (ax3.xaxis, ax3.yaxis, ax3.zaxis):
            axis.set_major_locator(MaxNLocator(4))
        ax3.set_xlabel(f"x ({unit})")
        ax3.set_ylabel(f"y ({unit})")
        ax3.set_zlabel("z (m)")
        for col, (i, j, xl, yl, title) in enumerate((
            (0, 2, f"x ({unit})", "z (m)", "side view"),
            (0, 1, f"x ({unit})", f"y ({unit})", "top view"),
        )):
            ax = fig.add_subplot(2, 3, row * 3 + 2 + col)
            lc = LineCollection(list(xy[:, :, [i, j]]), cmap=cmap, norm=norm, linewidths=0.5,
                                alpha=0.7)
            lc.set_array(vals)
            ax.add_collection(lc)
            ax.autoscale()
            if j == 1:
                ax.set_aspect("equal")
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            ax.set_title(title, fontsize=9)
        fig.colorbar(lc, ax=fig.axes[-1], label=label, shrink=0.85)
    fig.suptitle(f"{trace.n_agents} gliders, {trace.t[-1]:.0f} s "
                 "(top: coloured by time; bottom: by vertical speed)")
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
    axes[0].set_ylabel("height (m)")
    axes[1].set_ylabel("vertical speed (m/s)")
    axes[2].set_ylabel("cohesion |K_c c| (m/s²)")
    axes[2].set_xlabel("time (s)")
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
        ax.set_xlabel(f"{metric} (%)" if metric.endswith("Percent") else metric)
    axes[0][0].set_ylabel("runs (count)")
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
        ax.set_ylabel(f"mean {metric}" + (" (%)" if metric.endswith("Percent") else ""))
    return _save(fig, path)
