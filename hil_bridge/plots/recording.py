"""One figure of a recording (``echoloop launch --plot``): only the panels the run had.

Panels, each drawn only when the recording holds its data: the soaring swarm's tracks over
the thermals (gliders other than a sonar's mount), the sonar vehicle's path over the forest
leaves with the beam of the shown echo (its cone at the sonar's attitude when it pinged, from
the echo's pose and its ping's beamwidth, seen from above), and the last echo that heard leaves
as its envelope in dB re A0 over range.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.pose import cross

__all__ = ["beam_outline", "plot_recording"]

#: length of the beam cone drawn, m
BEAM_LENGTH_M = 3.0


def beam_outline(position: ArrayLike, boresight: ArrayLike, beamwidth: float, length: float,
                 n: int = 48) -> NDArray[np.float64]:
    """Points (n + 1, 3) of a beam cone: its apex at ``position``, then ``n`` points of its
    −3 dB rim ``length`` m along the ``boresight``."""
    b = np.asarray(boresight, dtype=np.float64)
    b = b / np.linalg.norm(b)
    u = cross(b, [0.0, 0.0, 1.0] if abs(b[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = cross(b, u)
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)[:, None]
    r = length * math.tan(beamwidth / 2.0)
    rim = np.asarray(position) + length * b + r * (np.cos(t) * u + np.sin(t) * v)
    return np.vstack([np.asarray(position, dtype=np.float64)[None], rim])


def _read(mcap: str | Path) -> dict[str, Any]:
    from hil_bridge.bus.codec import decode_payload
    from hil_bridge.recording.bag import read_bag

    got: dict[str, Any] = {"tracks": {}, "thermals": None, "leaves": None, "echo": None,
                           "mount": None, "echo_width": None}
    widths: dict[tuple[str, int], float] = {}
    for m in read_bag(mcap):
        topic = m.topic
        is_state = topic.startswith("/glider/") and topic.endswith("/state")
        is_sonar = topic.startswith("/sonar/") and topic.endswith(("/echo", "/ping"))
        if not (is_state or topic in ("/thermals", "/forest/points") or is_sonar):
            continue
        msg: Any = decode_payload(m.header.type, m.header.v, m.payload)
        if topic.endswith("/ping"):
            widths[(topic[:-5], int(msg.ping_seq))] = float(msg.beamwidth)
        elif is_state:
            got["tracks"].setdefault(int(topic.split("/")[2]), []).append((msg.x, msg.y))
        elif topic == "/thermals":
            got["thermals"] = msg
        elif topic == "/forest/points":
            got["leaves"] = msg
        else:
            # the last echo that heard leaves (an empty one says little), else the last
            echo = got["echo"]
            if echo is None or msg.leaves_in_beam > 0 or echo.leaves_in_beam == 0:
                got["echo"] = msg
                got["echo_width"] = widths.get((topic[:-5], int(msg.ping_seq)))
            frame = m.header.frame_id
            if frame.startswith("glider/") and frame[7:].isdigit():
                got["mount"] = int(frame[7:])
    return got


def plot_recording(mcap: str | Path, png: str | Path) -> dict[str, int]:
    """Write ``png`` from the recording ``mcap`` (module docstring); returns counts of what
    was drawn. ``ValueError`` if the recording has nothing to draw."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim_core.sonar.baseband import envelope_db

    got = _read(mcap)
    tracks, mount, echo = got["tracks"], got["mount"], got["echo"]
    swarm = {g: np.asarray(p) for g, p in sorted(tracks.items()) if g != mount}
    sonar_path = np.asarray(tracks[mount]) if mount in tracks else None
    panels = [name for name, present in (
        ("swarm", bool(swarm) or got["thermals"] is not None),
        ("sonar", sonar_path is not None or got["leaves"] is not None),
        ("echo", echo is not None)) if present]
    if not panels:
        raise ValueError(f"{mcap}: nothing to plot (no glider states, thermals, forest points "
                         "or echoes)")
    fig, axes = plt.subplots(1, len(panels), figsize=(5.6 * len(panels), 5.2), squeeze=False)
    beams = 0
    ax_of = dict(zip(panels, axes[0], strict=True))
    if "swarm" in ax_of:
        ax = ax_of["swarm"]
        extent = max((float(np.ptp(a)) for a in swarm.values()), default=0.0)
        scale, unit = (1e-3, "km") if extent > 2000.0 else (1.0, "m")
        th = got["thermals"]
        if th is not None:
            for x, y, r in zip(th.x, th.y, th.radius, strict=True):
                ax.add_patch(plt.Circle((x * scale, y * scale), r * scale, color="tab:orange",
                                        alpha=0.25, lw=0))
        for a in swarm.values():
            ax.plot(a[:, 0] * scale, a[:, 1] * scale, lw=1.0)
            ax.plot(a[-1, 0] * scale, a[-1, 1] * scale, "k^", ms=4)
        ax.autoscale()
        n_th = 0 if th is None else len(th.x)
        ax.set(title=f"{len(swarm)} gliders, {n_th} thermals (orange), ▲ last position",
               xlabel=f"x ({unit})", ylabel=f"y ({unit})", aspect="equal")
    if "sonar" in ax_of:
        ax = ax_of["sonar"]
        leaves = got["leaves"]
        if leaves is not None:
            ax.scatter(leaves.points[:, 0], leaves.points[:, 1], s=0.3, c="tab:green",
                       alpha=0.3, label="leaves", rasterized=True)
        if sonar_path is not None:
            ax.plot(sonar_path[:, 0], sonar_path[:, 1], "k-", lw=1.2,
                    label=f"sonar vehicle {mount}")
            ax.plot(sonar_path[-1, 0], sonar_path[-1, 1], "r^", ms=6)
        width = got["echo_width"]
        if (echo is not None and width is not None and np.all(np.isfinite(echo.position))
                and np.all(np.isfinite(echo.boresight))):
            from scipy.spatial import ConvexHull

            cone = beam_outline(echo.position, echo.boresight, width, BEAM_LENGTH_M)[:, :2]
            hull = cone[ConvexHull(cone).vertices]
            ax.fill(hull[:, 0], hull[:, 1], color="tab:red", alpha=0.3, lw=0,
                    label=f"beam of ping {echo.ping_seq} ({BEAM_LENGTH_M:g} m)")
            beams = 1
        ax.set(title="sonar vehicle over the forest (top view)", xlabel="x (m)",
               ylabel="y (m)", aspect="equal")
        ax.legend(loc="best", fontsize=8, markerscale=8)
    if "echo" in ax_of:
        ax = ax_of["echo"]
        samples = np.asarray(echo.samples, dtype=np.float64).reshape(-1, echo.samples.shape[-1])
        rng_m = np.arange(samples.shape[1]) / echo.fs * 340.0 / 2.0
        env = envelope_db(samples)
        peak = float(env.max())
        for c, row in enumerate(env):
            ax.plot(rng_m, row, lw=0.6, label=f"channel {c}" if len(env) > 1 else None)
        ax.axhline(peak, color="0.4", ls="--", lw=0.8)
        ax.set_ylim(peak - 80.0, peak + 6.0)
        ax.set(title=f"echo of ping {echo.ping_seq}: {echo.leaves_in_beam} leaves in beam, "
                     f"peak {peak:.1f} dB", xlabel="range (m, c = 340 m/s)",
               ylabel="envelope (dB re A0)")
        if len(env) > 1:
            ax.legend(fontsize=8)
    fig.tight_layout()
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return {"tracks": len(tracks), "echo": int(echo is not None), "beams": beams,
            "leaves": 0 if got["leaves"] is None else len(got["leaves"].points),
            "panels": len(panels)}
