"""The opt-in echo physics of :class:`sim_core.sonar.EchoParams` as ``echoloop echo`` options."""

from __future__ import annotations

import argparse
import math
from typing import Any

__all__ = ["add_physics_arguments", "physics_meta", "physics_params"]


def add_physics_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the physics options (all off by default: the echo is then the reference model)."""
    g = parser.add_argument_group("opt-in physics (docs/sonar.md)")
    g.add_argument("--absorption", action="store_true",
                   help="ISO 9613-1 air absorption over the two-way path")
    g.add_argument("--temperature", type=float, default=20.0, metavar="C",
                   help="air temperature for --absorption / --speed-from-temperature (20)")
    g.add_argument("--humidity", type=float, default=50.0, metavar="PCT",
                   help="relative humidity for --absorption, percent (50)")
    g.add_argument("--speed-from-temperature", action="store_true",
                   help="sound speed 331.3 sqrt(1 + T/273.15) instead of 340 m/s")
    g.add_argument("--call", choices=["fm", "cf-fm"], default=None,
                   help="emitted call convolved with the impulse response (default: none)")
    g.add_argument("--call-ms", type=float, default=2.0, metavar="MS",
                   help="length of the call's FM sweep, ms (2)")
    g.add_argument("--ears", default=None, metavar="SPACING_M[,SPLAY_DEG]",
                   help="binaural receivers this far apart, each turned SPLAY_DEG outwards "
                        "(15): one echo channel per ear")
    g.add_argument("--velocity", default=None, metavar="VX,VY,VZ",
                   help="platform velocity, m/s world ENU (moving-platform delays)")
    g.add_argument("--doppler", action="store_true",
                   help="Doppler shift from --velocity (reference fidelity only)")


def _floats(text: str, counts: tuple[int, ...], name: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in counts or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name}: expected {' or '.join(map(str, counts))} comma-separated "
                         f"finite numbers, got {text!r}")
    return values


def physics_params(args: argparse.Namespace) -> dict[str, Any]:
    """``EchoParams`` keyword arguments of the parsed physics options."""
    from sim_core.sonar import Call, Ear

    out: dict[str, Any] = {
        "absorption": args.absorption, "temperature_c": args.temperature,
        "humidity_pct": args.humidity, "speed_from_temperature": args.speed_from_temperature,
        "doppler": args.doppler,
    }
    if args.call is not None:
        if not args.call_ms > 0:
            raise ValueError(f"--call-ms: expected > 0 ms, got {args.call_ms}")
        out["call"] = Call(kind=args.call, duration_s=args.call_ms * 1e-3)
    if args.ears is not None:
        ears = _floats(args.ears, (1, 2), "--ears")
        if not ears[0] > 0:
            raise ValueError(f"--ears: spacing must be > 0 m, got {ears[0]}")
        out["ears"] = Ear.binaural(ears[0], math.radians(ears[1] if len(ears) > 1 else 15.0))
    if args.velocity is not None:
        out["platform_velocity"] = _floats(args.velocity, (3,), "--velocity")
    if args.doppler and args.velocity is None:
        raise ValueError("--doppler needs --velocity VX,VY,VZ")
    return out


def physics_meta(args: argparse.Namespace) -> dict[str, Any]:
    """The physics options as plain values for an echo file's ``ping`` record."""
    return {
        "absorption": bool(args.absorption), "temperature_c": float(args.temperature),
        "humidity_pct": float(args.humidity),
        "speed_from_temperature": bool(args.speed_from_temperature),
        "call": args.call or "none", "call_ms": float(args.call_ms) if args.call else 0.0,
        "ears": args.ears or "none",
        "platform_velocity": list(_floats(args.velocity, (3,), "--velocity"))
        if args.velocity else [0.0, 0.0, 0.0],
        "doppler": bool(args.doppler),
    }
