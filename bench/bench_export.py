"""Export throughput: a recording to ROS 2, Foxglove and MATLAB (``bag export``).

One synthetic recording shaped like a 20 s demo run (50 Hz states of 8 gliders and a sonar
vehicle, /clock, 10 Hz pings with 24000-sample echoes, thermals, 20,000 forest points), and
two single-kind recordings (states only, echoes only) to show where the time goes. Each
exporter runs 3 times; the table gives median process CPU time (the machine is shared, so
wall time swings with the other jobs) and messages per CPU second, beside two baselines
measured in the same run: reading and decoding the recording alone, and ``export --json``.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench._util import median, table

TITLE = "Recording export (ROS 2, Foxglove, MATLAB)"
REPEAT = 3


def _write(path: Path, kinds: set[str], seconds: float = 20.0) -> int:
    from mcap.well_known import MessageEncoding

    from hil_bridge.bus.codec import Header, encode_payload
    from hil_bridge.bus.messages import (
        Clock,
        GliderCmd,
        GliderState,
        PointCloud,
        SonarEcho,
        SonarPing,
        ThermalMarkers,
    )
    from hil_bridge.recording.bag_writer import BagWriter

    rng = np.random.default_rng(0)
    count = 0
    with open(path, "wb") as f:
        bag = BagWriter(f, chunk_size=64 * 1024, compression="zstd",
                         message_encoding=MessageEncoding.MessagePack, as_json=False)

        def add(topic: str, msg: Any, frame: str = "") -> None:
            nonlocal count
            hdr = Header(msg.TYPE, msg.VERSION, count, msg.stamp_ns, 0, frame, "bench#1")
            bag.add(topic, hdr, encode_payload(msg), 1_700_000_000_000_000_000 + msg.stamp_ns)
            count += 1

        if "world" in kinds:
            add("/thermals", ThermalMarkers(stamp_ns=0, x=rng.uniform(-3e3, 3e3, 9),
                                            y=rng.uniform(-3e3, 3e3, 9), radius=np.full(9, 60.0),
                                            w_max=np.full(9, 3.0)))
            add("/forest/points", PointCloud(
                stamp_ns=0, points=rng.uniform(-20, 20, (20000, 3)).astype(np.float32),
                intensity=np.full(20000, 0.02, np.float32), label="leaves"))
        for k in range(round(seconds * 50)):
            t = k * 20_000_000
            if "states" in kinds:
                add("/clock", Clock(stamp_ns=t))
                for gid in (*range(8), 100):
                    add(f"/glider/{gid}/state", GliderState(
                        stamp_ns=t, x=float(k + gid), y=float(gid), z=100.0, heading=0.01 * k,
                        bank=0.2, airspeed=11.0, vz=-0.8, glider_id=gid, step=k))
                if k % 25 == 0:
                    add("/glider/0/cmd", GliderCmd(stamp_ns=t, bank_cmd=0.2, airspeed_cmd=11.0,
                                                   glider_id=0, step=k))
            if "echoes" in kinds and k % 5 == 0:
                add("/sonar/0/ping", SonarPing(stamp_ns=t, ping_seq=k // 5, az=0.0, el=0.0,
                                               beamwidth=0.7))
                add("/sonar/0/echo", SonarEcho(
                    stamp_ns=t, ping_seq=k // 5, fs=400e3,
                    samples=rng.normal(0, 1e-3, 24000).astype(np.float32), leaves_in_beam=5000,
                    fidelity="fast"), "glider/100")
        bag.writer.finish()
    return count


def _cpu(fn: Callable[[], Any]) -> float:
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def run(out_dir: Path) -> str:
    from hil_bridge.recording.bag_writer import export_json
    from hil_bridge.recording.export import run_exporter
    from hil_bridge.recording.export.common import ExportCounts, decoded

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        bags = {
            "demo-like (all kinds)": {"world", "states", "echoes"},
            "states only": {"states"},
            "echoes only": {"echoes"},
        }
        for label, kinds in bags.items():
            src = d / "run.mcap"
            n = _write(src, kinds)
            size_mb = src.stat().st_size / 1e6

            def read_only(src: Path = src) -> None:
                for _ in decoded(src, ExportCounts()):
                    pass

            runs: dict[str, Callable[[], Any]] = {
                "read + decode (floor)": read_only,
                "--json (baseline)": lambda src=src: export_json(src, d / "out.json.mcap"),
            }
            for kind in ("ros2", "foxglove", "mat"):
                runs[f"--{kind}"] = (lambda kind=kind, src=src: run_exporter(
                    kind, src, d / f"out.{kind}", overwrite=True))
            base = None
            for name, fn in runs.items():
                times = []
                for _ in range(REPEAT):
                    for p in d.glob("out.*"):
                        p.unlink()
                    times.append(_cpu(fn))
                cpu = median(times)
                if name.startswith("--json"):
                    base = cpu
                rows.append([label if name.startswith("read") else "", f"{n} ({size_mb:.1f} MB)"
                             if name.startswith("read") else "", name, f"{cpu * 1e3:.0f}",
                             f"{n / cpu:,.0f}",
                             "" if base is None or name.startswith("read") else
                             f"{cpu / base:.2f}"])
    return (
        "Median process CPU time of 3 exports per row (`python -m bench export`); messages/s is "
        "recorded messages converted per CPU second; the last column is CPU time relative to "
        "`--json` on the same recording in the same run.\n\n"
        + table(["recording", "messages", "export", "CPU ms", "messages/s", "× --json"], rows)
    )
