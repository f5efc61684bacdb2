"""``echoloop ardupilot sitl [RUN OPTIONS]`` and ``echoloop ardupilot polar [--aircraft NAME]``.

``sitl`` is ``echoloop run drivers.ardupilot.sitl:ArduPilotSitl --name sitl``: the SITL JSON node
alone against a bus (the domain's, or ``--bus``), e.g. beside a launch on another host; every
option of ``echoloop run`` applies (``--param instances=[{vehicle_id: 7}]`` names the vehicles).
``polar`` flies a JSBSim aircraft's steady still-air glides (:mod:`sim_core.sixdof.polar`) and
prints them with ArduPilot's ``SOAR_POLAR_CD0``, ``SOAR_POLAR_B`` and ``SOAR_POLAR_K`` fitted to
them, lines a parameter file takes as they are.
"""

from __future__ import annotations

import argparse
import sys

from hil_bridge.cli import run as run_cli

ENTRY = "drivers.ardupilot.sitl:ArduPilotSitl"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="echoloop ardupilot",
                                description="ArduPilot SITL in the loop (JSON physics).")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("sitl", help="run the SITL JSON node against a bus (other options: those "
                                "of `echoloop run`)")
    pol = sub.add_parser("polar", help="fit ArduPilot's soaring polar to a JSBSim glider")
    pol.add_argument("--aircraft", default="sgs126", help="JSBSim model (default: sgs126)")
    pol.add_argument("--elevators", default="-0.3,-0.25,-0.2,-0.15,-0.1,-0.05",
                     help="elevator settings to glide on, comma-separated (normalised, JSBSim's "
                          "sign: negative is nose up)")
    pol.add_argument("--height", type=float, default=1500.0, help="start height m")
    return p


def main(argv: list[str] | None = None) -> int:
    args, rest = _parser().parse_known_args(sys.argv[1:] if argv is None else argv)
    if args.command == "sitl":
        return run_cli.main([ENTRY, "--name", "sitl", *rest])
    if rest:
        raise ValueError(f"echoloop ardupilot polar: unknown options {rest}")
    from sim_core.sixdof import SixDofSpec, fit_polar, measure_glides

    try:
        elevators = [float(v) for v in args.elevators.split(",")]
    except ValueError as exc:
        raise ValueError(f"--elevators: expected comma-separated numbers, got "
                         f"{args.elevators!r}") from exc
    glides, mass, area = measure_glides(SixDofSpec(aircraft=args.aircraft), elevators,
                                        height_m=args.height)
    polar = fit_polar(glides, mass, area)
    print(f"# {args.aircraft}: {mass:.1f} kg, wing area {area:.2f} m2; steady still-air "
          f"glides from {args.height:g} m")
    print("# elevator  airspeed_mps  sink_mps  glide_ratio  density_kg_m3")
    for gl in glides:
        print(f"# {gl.elevator:8.3f}  {gl.airspeed:12.2f}  {gl.sink:8.3f}  {gl.glide_ratio:11.1f}"
              f"  {gl.density:13.4f}")
    print(f"# best glide ratio of the fitted polar: {polar.best_glide_ratio:.1f}")
    print(f"SOAR_POLAR_CD0 {polar.cd0:.4f}")
    print(f"SOAR_POLAR_B {polar.b:.4f}")
    print(f"SOAR_POLAR_K {polar.k:.1f}")
    return 0
