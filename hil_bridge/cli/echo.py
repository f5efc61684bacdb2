"""``echoloop echo``: synthesise one foliage echo from a leaves file (sim_core.sonar).

Example::

    echoloop echo --leaves forest.npz --position 0,0,5 --boresight 30,0 --beamwidth 30 \\
        --out echo.npz --plot echo.png --json
    echoloop echo ... --absorption --temperature 25 --humidity 80 --call fm --ears 0.03 \\
        --out echo.mat --plot echo.png --spectrogram     # .npz, .mat (MATLAB v5) or .wav

``--seed2020`` gives the seed paper code's echo (``--beam-lookup``, ``--spreading`` override its
parts; docs/sonar.md, "The seed's own code").
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from hil_bridge.cli._echo_physics import add_physics_arguments, physics_meta, physics_params
from hil_bridge.files.config import load_npz
from hil_bridge.outputs import check_output
from hil_bridge.recording.export.echo_file import WAV_FORMATS, check_echo_output, write_echo
from sim_core.sonar import FIDELITIES, Beam, EchoParams, synthesize

__all__ = ["load_leaves", "main", "parse_floats"]


def parse_floats(text: str, count: int, name: str) -> tuple[float, ...]:
    """``"1,2,3"`` -> (1.0, 2.0, 3.0); ValueError naming ``name`` unless ``count`` finite."""
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise ValueError(f"{name} must be {count} comma-separated numbers, got {text!r}") from None
    if len(values) != count:
        raise ValueError(f"{name} must be {count} comma-separated numbers, got {text!r}")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name} must be finite, got {text!r}")
    return values


def load_leaves(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``centers`` (M, 3), ``normals`` (M, 3), ``radii`` (M,) from any ``.npz`` holding those
    arrays; ``ValueError`` naming the file for a damaged archive, a missing array or a wrong
    shape. Rows that are not finite are kept: the synthesiser drops and counts them."""
    data = load_npz(path)
    missing = [k for k in ("centers", "normals", "radii") if k not in data]
    if missing:
        raise ValueError(
            f"{path}: missing array(s) {missing}; a leaves file needs centers (M,3), "
            f"normals (M,3), radii (M,) (found {sorted(data)})"
        )
    centers, normals, radii = data["centers"], data["normals"], data["radii"]
    m = centers.shape[0] if centers.ndim == 2 else -1
    for name, arr, shape in (("centers", centers, (m, 3)), ("normals", normals, (m, 3)),
                             ("radii", radii, (m,))):
        if m < 0 or arr.shape != shape or arr.dtype.kind not in "iuf":
            raise ValueError(f"{path}: {name} has shape {arr.shape} ({arr.dtype}); expected "
                             f"numbers of shape {shape} (M = {m} leaves)")
    return centers, normals, radii


_VECTOR_OPTIONS = ("--position", "--boresight", "--velocity")


def _join_vector_values(argv: list[str]) -> list[str]:
    """``--position -10,0,8`` -> ``--position=-10,0,8``: argparse would take a value that
    starts with ``-`` (and is not a plain number) for an option."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in _VECTOR_OPTIONS and i + 1 < len(argv):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="echoloop echo", description="Synthesise one foliage echo (sim_core.sonar)."
    )
    parser.add_argument("--leaves", type=Path, required=True,
                        help=".npz with centers (M,3), normals (M,3), radii (M,) in metres")
    parser.add_argument("--position", required=True, metavar="X,Y,Z", help="sonar position, m")
    parser.add_argument("--boresight", required=True, metavar="AZ,EL",
                        help="beam azimuth (from +x towards +y) and elevation, degrees")
    parser.add_argument("--beamwidth", required=True, type=float, metavar="DEG",
                        help="full -3 dB beamwidth, degrees, in (0, 180)")
    parser.add_argument("--fidelity", default="fast", choices=sorted(FIDELITIES))
    parser.add_argument("--samples", type=int, default=EchoParams().samples, metavar="N",
                        help="echo length in samples at 400 kHz (default 24000 = 60 ms)")
    parser.add_argument("--spreading", action=argparse.BooleanOptionalAction, default=None,
                        help="the 1/r^2 spreading loss (default: on; off with --seed2020)")
    parser.add_argument("--seed2020", action="store_true",
                        help="the seed paper's echo code (Demonstration_code_for_Paper): "
                             "Gaussian in raw az/el read from its 1 deg grid, no 1/r^2")
    parser.add_argument("--beam-lookup", choices=("exact", "grid"),
                        help="with --seed2020: the seed's 1 deg grid (default) or the Gaussian "
                             "at each leaf's own angles")
    parser.add_argument("--out", type=Path,
                        help="write the echo, fs and the ping's parameters to .npz, .mat "
                             "(MATLAB v5) or .wav, by extension")
    parser.add_argument("--wav-format", choices=WAV_FORMATS, default="float32",
                        help="WAV samples: float32 (values re A0) or int16 (peak = 32767)")
    parser.add_argument("--plot", type=Path,
                        help="PNG: waveform and envelope in dB re A0 (--spectrogram adds one)")
    parser.add_argument("--spectrogram", action="store_true", help="add a spectrogram panel")
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")
    add_physics_arguments(parser)
    args = parser.parse_args(_join_vector_values(argv))
    if args.plot is not None:  # refuse before computing anything (--out: check_echo_output)
        check_output(args.plot, overwrite=args.overwrite, inputs=[args.leaves])

    position = parse_floats(args.position, 3, "--position")
    az, el = parse_floats(args.boresight, 2, "--boresight")
    if not (math.isfinite(args.beamwidth) and 0.0 < args.beamwidth < 180.0):
        raise ValueError(f"--beamwidth must be in (0, 180) degrees, got {args.beamwidth!r}")
    beam = Beam.from_az_el(position, math.radians(az), math.radians(el),
                           math.radians(args.beamwidth))
    if args.beam_lookup is not None and not args.seed2020:
        raise ValueError(f"--beam-lookup {args.beam_lookup} needs --seed2020 (docs/sonar.md)")
    params = EchoParams(samples=args.samples, spreading=args.spreading, seed2020=args.seed2020,
                        beam_lookup=args.beam_lookup, **physics_params(args))
    if args.out is not None:
        check_echo_output(args.out, overwrite=args.overwrite)
    leaves = load_leaves(args.leaves)
    t0 = time.perf_counter()
    echo = synthesize(leaves, beam, params, fidelity=args.fidelity)
    seconds = time.perf_counter() - t0
    written: dict[str, object] = {}
    if args.out is not None:
        meta = {"position": list(position), "az_deg": az, "el_deg": el,
                "beamwidth_deg": args.beamwidth, "fidelity": echo.fidelity,
                "leaves_in_beam": echo.leaves_in_beam, "sound_speed": params.sound_speed,
                "spreading": params.spreading, "seed2020": params.seed2020,
                "beam_lookup": params.beam_lookup, **physics_meta(args)}
        written = write_echo(args.out, echo.samples, echo.fs, meta, overwrite=args.overwrite,
                             wav_format=args.wav_format)
    if args.plot is not None:
        from hil_bridge.outputs import atomic_output
        from hil_bridge.plots.sonar import plot_echo

        with (atomic_output(args.plot, overwrite=args.overwrite, inputs=[args.leaves]) as tmp,
              open(tmp, "wb") as fh):
            plot_echo(echo.samples, echo.fs, fh, sound_speed=params.sound_speed,
                      spectrogram=args.spectrogram, band=(params.f_lo, params.f_hi),
                      title=f"{echo.leaves_in_beam} leaves in beam, {args.fidelity}")
    summary = {
        "leaves_in_beam": echo.leaves_in_beam,
        "dropped": echo.dropped,
        "fidelity": echo.fidelity,
        "samples": int(echo.samples.shape[-1]),
        "fs": echo.fs,
        "seconds": seconds,
        "error_bound": echo.error_bound,
        "peak": float(np.abs(echo.samples).max()),
        "channels": int(np.atleast_2d(echo.samples).shape[0]),
        **{f"out_{k}": v for k, v in written.items()},
    }
    if echo.dropped:
        print(f"echoloop echo: warning: {args.leaves}: {echo.dropped} leaves dropped (rows "
              "not finite, or a zero normal or radius)", file=sys.stderr)
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"{echo.leaves_in_beam} leaves in beam ({echo.dropped} dropped), "
            f"{summary['samples']} samples at {echo.fs:.0f} Hz, {echo.fidelity} in "
            f"{seconds * 1e3:.2f} ms, peak {summary['peak']:.3g}"
        )
    return 0
