"""Arguments shared by several ``echoloop`` commands: ``--domain`` and durations in seconds."""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterator

from hil_bridge.bus.domain import (
    DOMAIN_ENV,
    MAX_DOMAIN,
    Domain,
    claim_first_free,
    current,
    parse_domain,
)

__all__ = ["add_domain_argument", "domain_for_run", "domain_from", "seconds"]


def seconds(text: str) -> float:
    """argparse type: a finite number of seconds > 0 (NaN, 0, negatives and inf rejected)."""
    from hil_bridge.launch.runner import check_duration

    try:
        return check_duration(text, where="")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _domain(text: str) -> str:
    if text.strip() != "auto":
        try:
            parse_domain(text, where="--domain")
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix("--domain=")) from None
    return text.strip()


def add_domain_argument(parser: argparse.ArgumentParser, *, auto: bool = False) -> None:
    """``--domain N`` (``auto`` too when ``auto``): the domain whose ports, pty links and
    virtual CAN channels this command uses (default ``$ECHOLOOP_DOMAIN``, else 0)."""
    extra = "; 'auto': the first free one from there" if auto else ""
    parser.add_argument(
        "--domain", type=_domain, default=None, metavar="N",
        help=f"domain 0..{MAX_DOMAIN}: its bus ports, pty links and virtual CAN channels "
             f"(default ${DOMAIN_ENV}, else 0{extra})",
    )


def domain_from(args: argparse.Namespace, prog: str) -> Domain:
    """The domain an invocation asked for (``--domain N``, else :func:`current`)."""
    choice = getattr(args, "domain", None)
    if choice is None:
        return current()
    if choice == "auto":
        raise ValueError(f"{prog}: --domain auto is for commands that run nodes (launch)")
    return Domain(parse_domain(choice, where="--domain"))


@contextlib.contextmanager
def domain_for_run(args: argparse.Namespace, prog: str) -> Iterator[Domain]:
    """:func:`domain_from`; with ``--domain auto`` the first free domain, claimed for the
    block, saying on stderr which domains were busy."""
    if getattr(args, "domain", None) != "auto":
        yield domain_from(args, prog)
        return
    with claim_first_free() as (dom, skipped):
        for busy, reason in skipped:
            print(f"{prog}: {busy} is busy ({reason})", file=sys.stderr)
        if skipped:
            print(f"{prog}: using {dom} (set {DOMAIN_ENV}={dom.number} or pass --domain "
                  f"{dom.number} to reach it with other commands)", file=sys.stderr, flush=True)
        yield dom
