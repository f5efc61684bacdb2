"""Eight sonar vehicles at 20 Hz on the machine's cores: one echo worker, the pool, echo nodes.

``launch/bench_multisonar.yaml`` (8 sonar vehicles on figure-eights in a 978,432-leaf tiled
maple forest, each pinged at 20 Hz with beamwidths U(30°, 65°), states at 250 Hz, realtime
clock) is launched as ``echoloop launch`` does (a claimed domain, its ZeroMQ bus, every node a
process of its own) for ``RUN_S`` wall seconds, several times in the same run:
``echo_worker: thread`` (one worker: the server's echo thread, the single-worker path),
``echo_worker: pool`` (one worker process per usable core fed by the server's scheduler,
tiles shared in memory, deadlines) and ``echo_worker: auto``, which picks echo nodes here (one
process per usable core, each taking its sonars' pings from the bus and publishing their
echoes itself: docs/server.md). Figures are the server's summary over the whole run
(the echo nodes' counters merged into it), start-up included: *answered* =
``echoes_published / pings_received``; ping → echo is ping received → echo published, where
the echo is computed;
*late ticks* are ticks that started more than one tick period behind the wall clock; *dropped* =
``pings_dropped`` (full queue) + ``pings_dropped_deadline`` (superseded by the sonar's next ping or
out of time), *degraded* = echoes computed at ``realtime`` fidelity within the time left, *late
echoes* = published after their deadline (their sonar's next ping, or the budget). CPU is user +
system time of this process (the launcher and its bus monitor) and of its (reaped) child processes
over the run: the node processes (server, pinger) and the echo workers or nodes; the fourth row
starts the pinger apart from the launch, with no launcher of its own, as a hardware head would be,
and the row after it gives the echoes a latency budget (``echo_budget_ms`` = ``BUDGET_MS``: an echo
is also due that long after its ping arrived, degraded or dropped when it cannot be ready by then;
docs/server.md). *At fidelity* = (``echoes_published`` - ``echoes_degraded``) / ``pings_received``.
The last column is the stall probe beside each run (``bench._util.StallProbe``: a thread at
``SCHED_FIFO`` 95 waking every 1 ms): wake-ups more than 3 ms late, and the latest, stalls of the
platform that held every process of that run.
Issue 19's goal on 2 cores: ≥ 99 % answered at the scene's fidelity, p99 ≤ 25 ms, late ticks ≤ 1 %.
"""

from __future__ import annotations

import resource
from pathlib import Path
from typing import Any

from bench._util import StallProbe, table
from hil_bridge.bus.domain import claim_first_free
from hil_bridge.files.config import load_yaml
from hil_bridge.launch.runner import run as launch_run

TITLE = "Eight sonar vehicles × 20 Hz: one echo worker, the pool and echo nodes; sixteen"

ROOT = Path(__file__).resolve().parent.parent
LAUNCH = ROOT / "launch" / "bench_multisonar.yaml"
RUN_S = 20.0
#: how long the pinger's own process takes to start (imports), added to the server's run (s)
PINGER_START_S = 4.0
#: the latency budget of the last row (ms): issue 19's ping → echo p99 goal
BUDGET_MS = 25.0


def _cpu() -> tuple[float, float]:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime


def _pinger_apart(spec: dict[str, Any], domain: Any, run_s: float, out: Any) -> None:
    """Child process: the launch file's pinger alone (no bus monitor), on the server's bus."""
    import time

    from hil_bridge.replay.trajectory import Pinger

    node = spec["nodes"][1]
    pinger = Pinger(node["name"], bus=domain.bus_url, **node["params"])
    pinger.start()
    time.sleep(run_s)
    pinger.stop()
    out.put(pinger.stats())


def _sixteen(spec: dict[str, Any]) -> None:
    """``spec`` with eight more sonar vehicles (ids 8..15): the same eights 3 m higher, in the
    same forest, and the pinger pinging all sixteen."""
    scene = spec["nodes"][0]["params"]["scene"]
    more = []
    for v in scene["vehicles"]:
        params = {**v["path"]["params"], "altitude": v["path"]["params"]["altitude"] + 3.0}
        more.append({**v, "id": v["id"] + 8, "path": {**v["path"], "params": params}})
    scene["vehicles"] += more
    scene["sonars"] += [{**s, "id": s["id"] + 8, "mount": s["mount"] + 8}
                        for s in scene["sonars"]]
    spec["nodes"][1]["params"]["sonar_ids"] = list(range(16))


def measure(worker: str, run_s: float = RUN_S, *, pinger_apart: bool = False,
            budget_ms: float | None = None, sixteen: bool = False) -> dict[str, Any]:
    """One run of the scene with ``echo_worker: worker``: the server's and pinger's summary.
    ``pinger_apart``: the pinger in its own process (as hardware heads are), started once the
    server runs; the server then runs ``PINGER_START_S`` longer. ``budget_ms``: the server's
    ``echo_budget_ms``. ``sixteen``: sixteen sonar vehicles (:func:`_sixteen`)."""
    import multiprocessing

    spec = load_yaml(LAUNCH)
    if sixteen:
        _sixteen(spec)
    spec["nodes"][0]["params"]["echo_worker"] = worker
    spec["nodes"][0]["params"]["echo_budget_ms"] = budget_ms
    own0, kids0 = _cpu()
    ctx = multiprocessing.get_context("spawn")
    got = ctx.Queue()
    child: list[Any] = []
    with claim_first_free() as (domain, _):
        def start_pinger(_spec: Any) -> None:
            proc = ctx.Process(target=_pinger_apart, args=(spec, domain, run_s, got))
            proc.start()
            child.append(proc)

        if pinger_apart:
            summary = launch_run({**spec, "nodes": [spec["nodes"][0]]},
                                 duration=run_s + PINGER_START_S, domain=domain,
                                 handle_signals=False, on_started=start_pinger)
            pinger = got.get(timeout=60)
            child[0].join()
        else:
            summary = launch_run(spec, duration=run_s, domain=domain, handle_signals=False)
            pinger = summary.nodes["pinger"]
    own1, kids1 = _cpu()
    if summary.failures:
        raise RuntimeError(f"bench_multisonar ({worker}): {summary.failures}")
    return {"worker": worker, "apart": pinger_apart, "budget_ms": budget_ms, "sixteen": sixteen,
            "server": summary.nodes["server"],
            "pinger": pinger, "cpu_server_s": own1 - own0, "cpu_workers_s": kids1 - kids0}


def row(r: dict[str, Any]) -> list[Any]:
    s = r["server"]
    pings = max(1, s["pings_received"])
    ticks = max(1, s["ticks"])
    label = {"thread": "1 worker (echo thread)",
             "pool": f"pool of {s['echo_workers']} processes"}.get(
                 s["echo_worker"], f"auto: {s['echo_workers']} echo {s['echo_worker']}")
    if r["apart"]:
        label += ", pinger in its own process"
    if r["budget_ms"] is not None:
        label += f", echo_budget_ms {r['budget_ms']:g}"
    if r["sixteen"]:
        label = f"**16 sonars**, {label}"
    return [
        label, s["pings_received"], f"{100.0 * s['echoes_published'] / pings:.1f}",
        f"{100.0 * (s['echoes_published'] - s['echoes_degraded']) / pings:.1f}",
        f"{s['ping_echo_ms']['p50']:.1f} / {s['ping_echo_ms']['p99']:.1f}",
        f"{s['echo_compute_ms']['p50']:.1f}",
        f"{s['ticks']}", f"{100.0 * s['late_ticks'] / ticks:.2f}",
        f"{s['pings_dropped']} + {s['pings_dropped_deadline']}",
        s["echoes_degraded"], s["echoes_late"], s["echo_errors"],
        s["echo_tiles_prefetched"],
        f"{r['cpu_server_s']:.1f} + {r['cpu_workers_s']:.1f}",
        f"{r['probe']['over_3ms']} / {r['probe']['max_ms']:.1f}",
    ]


HEADER = ["echo workers", "pings", "answered %", "at fidelity %", "ping → echo p50 / p99 ms",
          "echo compute p50 ms", "ticks", "late ticks %", "dropped (queue + deadline)",
          "degraded", "late echoes", "errors", "tiles built ahead",
          "CPU s (launcher + node processes)", "platform stalls > 3 ms / latest ms (probe)"]




BEAMWIDTHS_DEG = (30.0, 45.0, 65.0)
COST_REPEAT = 5


def cost_rows() -> list[dict[str, Any]]:
    """CPU time of gathering and synthesising (``fast``) one echo of each sonar of the scene
    from three points of its route, at each of :data:`BEAMWIDTHS_DEG`, against the cost model
    (:data:`sim_core.sonar.cost.COST`): medians of :data:`COST_REPEAT` calls, tiles built."""
    import functools
    import time
    from unittest.mock import patch

    import numpy as np

    from hil_bridge.files.scene import load_scene
    from sim_core.pose import quat_from_euler
    from sim_core.sonar import api, fast, synthesize
    from sim_core.sonar.cost import COST
    from sim_core.sonar.model import _Selection, precull_half_angle
    from sim_core.sonar.mount import ping_beam

    double_check = functools.partial(_double_check, fast._interpolation_error)
    double_assemble = functools.partial(_double_assemble, api.assemble)
    spec = load_yaml(LAUNCH)["nodes"][0]["params"]["scene"]
    scene = load_scene(spec)
    out = []
    for sonar in scene.spec.sonars:
        traj = scene.trajectories[sonar.mount]
        for t in (0.0, 4.0, 8.0):
            s = traj.sample(np.array([t, t + 0.1]))
            xyz = np.column_stack([s["x"], s["y"], s["z"]])
            yaw = float(np.arctan2(*(xyz[1, 1::-1] - xyz[0, 1::-1])))
            p = xyz[0]
            q = quat_from_euler(0.0, sonar.mount_rpy_rad[1], yaw)
            radius = scene.query_radius_m(sonar.id)
            params = scene.echo_params(sonar.id)
            for bw in BEAMWIDTHS_DEG:
                beam = ping_beam(p, q, 0.0, 0.0, np.radians(bw))
                scene.leaves_near(p, radius)  # its tiles built
                _kdtree_gather(scene.forest_source, p, radius)  # the tiles' k-d trees built
                gather, synth, kdtree, numpy_synth = [], [], [], []
                for _ in range(COST_REPEAT):
                    c0 = time.process_time()
                    leaves = scene.leaves_near(p, radius)
                    c1 = time.process_time()
                    echo = synthesize(leaves, beam, params, fidelity="fast")
                    c2 = time.process_time()
                    baseline = _kdtree_gather(scene.forest_source, p, radius)
                    c3 = time.process_time()
                    with (patch.object(_Selection, "cull", _numpy_cull),
                          patch.object(fast, "_interpolation_error", double_check),
                          patch.object(api, "assemble", double_assemble)):
                        c4 = time.process_time()
                        old = synthesize(leaves, beam, params, fidelity="fast")
                        c5 = time.process_time()
                    gather.append(c1 - c0)
                    synth.append(c2 - c1)
                    kdtree.append(c3 - c2)
                    numpy_synth.append(c5 - c4)
                if baseline != leaves:
                    raise AssertionError(f"sonar {sonar.id} t={t}: the k-d tree gathers other "
                                         "leaves")
                # sums of squares, not np.linalg.norm: OpenBLAS's threads would spin on after it
                # and their CPU time would count in the next timings
                diff = float(np.square(old.samples - echo.samples).sum())
                if diff > (echo.error_bound or 0.0) ** 2 * float(np.square(old.samples).sum()):
                    raise AssertionError(f"sonar {sonar.id} t={t}: the baseline's echo differs "
                                         "by more than the echo's error bound")
                n = len(leaves)
                out.append({"bw": bw, "n": n, "gather": float(np.median(gather)),
                            "kdtree": float(np.median(kdtree)),
                            "synth": float(np.median(synth)),
                            "numpy_synth": float(np.median(numpy_synth)),
                            "gather_model": COST.gather_s * n,
                            "synth_model": COST.estimate(n, precull_half_angle(beam, params))})
    return out


def _numpy_cull(sel: Any, c: Any, n: Any, a: Any, rows: Any, ws: Any) -> tuple[Any, ...]:
    """The baseline of the selection's pre-cull: ``sim_core.sonar.model._Selection.cull`` as
    numpy computed it before ``sim_core/sonar/precull.py`` (blocks of ``GEOMETRY_BLOCK`` leaves,
    the guards, range and cone as array passes, then the survivors compacted); the offsets are
    not gathered (only the ``seed2020`` off-axis form needs them, and the scene has none)."""
    import math

    import numpy as np

    from sim_core.sonar.geometry import GEOMETRY_BLOCK

    total = c.shape[0] if rows is None else rows.shape[0]
    out_rows, out_r = np.empty(total, np.intp), np.empty(total)
    out_proj, out_nd = np.empty(total), np.empty(total)
    found = dropped = 0
    pos, axis = sel.pos, sel.axis
    for start in range(0, total, GEOMETRY_BLOCK):
        stop = min(start + GEOMETRY_BLOCK, total)
        if rows is None:
            cb, nb, ab = c[start:stop], n[start:stop], a[start:stop]
        else:
            rb = rows[start:stop]
            cb, nb, ab = c.take(rb, axis=0), n.take(rb, axis=0), a.take(rb)
        dx, dy, dz = cb[:, 0] - pos[0], cb[:, 1] - pos[1], cb[:, 2] - pos[2]
        nx, ny, nz = nb[:, 0], nb[:, 1], nb[:, 2]
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            r2 = dx * dx
            r2 += dy * dy
            r2 += dz * dz
            nn2 = nx * nx
            nn2 += ny * ny
            nn2 += nz * nz
            valid = nn2 > 0.0
            valid &= r2 >= sel.r_min2
            if not math.isfinite(float(r2.sum()) + float(nn2.sum()) + float(ab.sum())):
                valid &= np.isfinite(dx + dy + dz + (nx + ny + nz) + ab)
            dropped += ab.shape[0] - int(np.count_nonzero(valid))
            valid &= r2 <= sel.reach2
            r = np.sqrt(r2, out=r2)
            proj = dx * axis[0]
            proj += dy * axis[1]
            proj += dz * axis[2]
            if sel.cone:
                valid &= proj >= sel.cos_reach * r
            nd = nb[:, 0] * dx
            nd += nb[:, 1] * dy
            nd += nb[:, 2] * dz
            nd /= np.sqrt(nn2, out=nn2)
        hit = np.flatnonzero(valid)
        k = hit.shape[0]
        out_rows[found:found + k] = hit + start if rows is None else rows[start:stop][hit]
        out_r[found:found + k] = r.compress(valid)
        out_proj[found:found + k] = proj.compress(valid)
        out_nd[found:found + k] = nd.compress(valid)
        found += k
    return (found, dropped, out_rows[:found], out_r[:found], out_proj[:found],
            np.empty((found, 3)), out_nd[:found])


def _double_check(check: Any, *args: Any, single: bool) -> tuple[float, float]:
    """The baseline of ``fast``'s interpolation ``check``: in float64 whatever the synthesis's
    precision, as it ran before it took the synthesis's precision."""
    return check(*args, single=False)  # type: ignore[no-any-return]


def _double_assemble(assemble: Any, spectra: Any, lo_bin: int, params: Any) -> Any:
    """The baseline of the output transform (``assemble``): in complex128 whatever the
    spectra's precision, as it ran before ``fast`` kept its spectra in complex64."""
    import numpy as np

    return assemble(spectra.astype(np.complex128), lo_bin, params)


def _kdtree_gather(forest: Any, p: Any, r: float) -> Any:
    """The baseline: the leaves near ``p`` as ``TiledForest.leaves_near`` gathered them before
    its compiled ball test (a k-d tree per tile, ``query_ball_point``, sorted indices)."""
    from sim_core.world.leaves import Leaves

    parts, offset = [], 0
    for t in forest.tiles_near(p, r):
        tile = forest.ensure(t)
        if len(tile.leaves):
            idx = tile.leaves.query_ball(p, r)
            if idx.size:
                sub = tile.leaves.select(idx)
                parts.append(Leaves(sub.centers, sub.normals, sub.radii, sub.tree_id + offset))
        offset += tile.tree_xy.shape[0]
    return Leaves.concat(parts)


def cost_table(rows: list[dict[str, Any]]) -> str:
    import numpy as np

    lines = []
    for bw in BEAMWIDTHS_DEG:
        for lo, hi in ((0, 20_000), (20_000, 40_000), (40_000, 10**9)):
            sel = [r for r in rows if r["bw"] == bw and lo <= r["n"] < hi]
            if not sel:
                continue

            def med(key: str, sel: list[dict[str, Any]] = sel) -> float:
                return float(np.median([r[key] for r in sel]))

            lines.append([
                f"{bw:g}°", f"{lo:,}–{hi:,}" if hi < 10**9 else f"≥ {lo:,}", len(sel),
                f"{med('n'):,.0f}", f"{1e3 * med('gather'):.2f} ({1e3 * med('gather_model'):.2f})",
                f"{1e3 * med('kdtree'):.2f}",
                f"{1e3 * med('synth'):.2f} ({1e3 * med('synth_model'):.2f})",
                f"{1e3 * med('numpy_synth'):.2f}",
                f"{(med('gather') + med('synth')) / (med('kdtree') + med('numpy_synth')):.2f}",
                f"{med('synth') / med('synth_model'):.2f}",
            ])
    ratio = float(np.median([r["synth"] / r["synth_model"] for r in rows]))
    gather = float(np.median([r["gather"] / max(1, r["n"]) for r in rows]))
    kdtree = float(np.median([r["kdtree"] / max(1, r["n"]) for r in rows]))
    echo = float(np.median([(r["gather"] + r["synth"]) / (r["kdtree"] + r["numpy_synth"])
                            for r in rows]))
    pre = float(np.median([r["synth"] / r["numpy_synth"] for r in rows]))
    return (
        table(["beamwidth", "leaves in range", "pings", "median leaves",
               "gather CPU ms (model)", "k-d tree gather CPU ms (baseline)",
               "fast echo CPU ms (model)", "fast echo CPU ms as issue 19 found it (baseline)",
               "echo CPU / baseline", "measured / model"],
              lines)
        + f"\n\nAll {len(rows)} pings: measured / model {ratio:.2f} (median); gathering "
        f"{1e9 * gather:.0f} ns per leaf in range (model {1e9 * _gather_s():.0f} ns), against "
        f"{1e9 * kdtree:.0f} ns with the k-d trees of the baseline (the gather before "
        f"`sim_core/world/ball.py`, measured beside it: the same leaves, same order); the "
        f"`fast` synthesis takes {pre:.2f} of its CPU time as issue 19 found it (the numpy "
        f"pre-cull before `sim_core/sonar/precull.py`, the interpolation check in float64 and "
        f"the output transform in complex128 before they ran in the synthesis's precision, "
        f"measured beside it: the same echo within its error bound); a whole echo (gather + "
        f"`fast`) takes {echo:.2f} of the baseline's (the k-d tree gather and that synthesis: "
        f"the echo as issue 19 found it) (median).\n"
    )


_KERNEL_COST = (
    "import time, numba, sim_core.world, sim_core.world.ball as b, sim_core.sonar.precull as p\n"
    "t = time.process_time(); b.warm_up(); p.warm_up(); print(time.process_time() - t)\n"
)


def kernel_cost() -> tuple[float, float]:
    """CPU seconds of :func:`sim_core.world.ball.warm_up` and
    :func:`sim_core.sonar.precull.warm_up` in a fresh process: compiling (an empty numba
    cache) and loading from the cache they left (numba and the world imported)."""
    import os
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        out = [float(subprocess.run([sys.executable, "-c", _KERNEL_COST], env=env, check=True,
                                    capture_output=True, text=True).stdout)
               for _ in range(2)]
    return out[0], out[1]


def _gather_s() -> float:
    from sim_core.sonar.cost import COST

    return COST.gather_s


def _probed(worker: str, **kwargs: Any) -> dict[str, Any]:
    """:func:`measure` with the stall probe beside it (``probe``: its result)."""
    with StallProbe() as probe:
        r = measure(worker, **kwargs)
    return r | {"probe": probe.result}


def run(out_dir: Path) -> str:
    rows = [_probed("thread"), _probed("pool"), _probed("auto"),
            _probed("auto", pinger_apart=True), _probed("auto", budget_ms=BUDGET_MS),
            _probed("auto", sixteen=True)]
    one, pool, auto = (r["server"] for r in rows[:3])

    def late(s: dict[str, Any]) -> float:
        return 100.0 * s["late_ticks"] / max(1, s["ticks"])

    return (
        f"{__doc__}\n{RUN_S:.0f} s each, the same run:\n\n{table(HEADER, [row(r) for r in rows])}"
        f"\n\nPing → echo p99 against one worker: pool × "
        f"{pool['ping_echo_ms']['p99'] / one['ping_echo_ms']['p99']:.2f}, auto ("
        f"{auto['echo_worker']}) × {auto['ping_echo_ms']['p99'] / one['ping_echo_ms']['p99']:.2f}"
        f"; late ticks: one worker {late(one):.2f} %, pool {late(pool):.2f} %, auto "
        f"{late(auto):.2f} %. The last row: sixteen sonar vehicles (ids 8-15 on the same "
        "eights 3 m higher, 320 pings a second), issue 44's goal ≥ 99 % answered, "
        "p99 ≤ 25 ms, ≤ 1 % late ticks.\n\n"
        "### Echo cost against the cost model\n\n"
        "One ping of each sonar from three points of its route (t = 0, 4, 8 s) at each "
        "beamwidth, in this process (one core): CPU time of gathering the leaves in range "
        "from built tiles and of the `fast` synthesis, medians of "
        f"{COST_REPEAT} calls, beside `sim_core.sonar.cost.COST` (docs/sonar.md) and beside "
        "the baseline of issue 19's goal (a `fast` echo at ≤ ½ of its CPU time): the echo as "
        "the issue found it, the leaves gathered with k-d trees, selected with numpy's "
        "pre-cull, checked in float64 and transformed in complex128, both measured in the "
        "same loop.\n\n"
        f"{cost_table(cost_rows())}"
        "\nThe compiled kernels' own cost, once per process (CPU s of `ball.warm_up()` and "
        "`precull.warm_up()`, the leaf gather and the selection's pre-cull, in a fresh "
        "process, numba imported): compiling them into an empty cache {:.2f} s, loading them "
        "from that cache {:.2f} s (`make` compiles them at install; the server's echo workers "
        "and nodes load them before their first ping).\n".format(*kernel_cost())
    )
