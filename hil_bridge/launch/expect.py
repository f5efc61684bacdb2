"""Run checks for CI: ``--expect 'NODE.COUNTER OP VALUE'`` against a launch's run summary.

An expectation names a node of the launch, a key of that node's ``stats()`` (the ``nodes``
section of ``echoloop launch --json``; a dotted path reaches nested values, e.g.
``server.ping_echo_ms.p99``), an operator (``> >= < <= == !=``) and a value, spaces optional::

    server.stalls == 0
    sonar_head_mock.echoes_complete>=10
    server.clock_mode == lockstep

Numbers compare as numbers (a NaN counter fails every comparison but ``!=``); ``==`` and ``!=``
also compare words. The node must exist in the launch file (checked before the run); a counter
the node did not report makes the expectation fail, naming the counters it has.
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["OPERATORS", "Expectation", "parse_expectations"]

#: operator text -> comparison
OPERATORS: dict[str, Callable[[Any, Any], bool]] = {
    ">=": operator.ge, "<=": operator.le, "==": operator.eq, "!=": operator.ne,
    ">": operator.gt, "<": operator.lt,
}
_FORM = "'NODE.COUNTER OP VALUE' with OP one of > >= < <= == !="
_RE = re.compile(
    r"^\s*(?P<node>[A-Za-z0-9_]+)\.(?P<key>[^\s<>=!]+)\s*(?P<op>>=|<=|==|!=|>|<)\s*"
    r"(?P<value>\S(?:.*\S)?)\s*$"
)


def _as_number(value: Any) -> float | None:
    """A counter as a float (bools as 0/1, numpy scalars too); None for words and mappings."""
    if isinstance(value, str) or value is None or isinstance(value, Mapping | list | tuple):
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value


@dataclass(frozen=True, slots=True)
class Expectation:
    """One parsed ``NODE.COUNTER OP VALUE`` (see the module docstring)."""

    node: str
    key: str
    op: str
    value: str

    @classmethod
    def parse(cls, text: str) -> Expectation:
        """Parse one expectation; ``ValueError`` naming the text and the expected form."""
        m = _RE.match(text)
        if m is None:
            raise ValueError(f"--expect {text!r}: expected {_FORM}")
        value = m["value"]
        if m["op"] not in ("==", "!=") and _number(value) is None:
            raise ValueError(f"--expect {text!r}: {m['op']} needs a number, got {value!r}")
        return cls(m["node"], m["key"], m["op"], value)

    def __str__(self) -> str:
        return f"{self.node}.{self.key} {self.op} {self.value}"

    def _lookup(self, stats: Mapping[str, Any]) -> tuple[bool, Any]:
        if self.key in stats:
            return True, stats[self.key]
        here: Any = stats
        for part in self.key.split("."):
            if not isinstance(here, Mapping) or part not in here:
                return False, None
            here = here[part]
        return True, here

    def check(self, nodes: Mapping[str, Mapping[str, Any]]) -> str | None:
        """None if it holds for the run's ``nodes`` stats, else one line saying why not."""
        stats = nodes.get(self.node)
        if stats is None:
            return f"expectation {self}: no node {self.node!r} ran (nodes: {sorted(nodes)})"
        found, got = self._lookup(stats)
        if not found:
            return (f"expectation {self}: node {self.node!r} has no counter {self.key!r} "
                    f"(counters: {sorted(stats)})")
        compare = OPERATORS[self.op]
        want, number = _number(self.value), _as_number(got)
        if number is not None and want is not None:
            ok = (math.isnan(number) or number != want) if self.op == "!=" else (
                not math.isnan(number) and compare(number, want))
        elif self.op in ("==", "!=") and not isinstance(got, Mapping | list | tuple):
            ok = compare(str(got).lower(), self.value.lower())
        else:
            return f"expectation {self}: {self.node}.{self.key} is not a number ({got!r})"
        return None if ok else f"expectation {self} failed: {self.node}.{self.key} = {got!r}"


def parse_expectations(
    items: Iterable[str], *, nodes: Iterable[str] | None = None
) -> list[Expectation]:
    """Parse every ``--expect``; with ``nodes`` (the launch's node names) an unknown node
    raises ``ValueError`` before anything runs."""
    out = [Expectation.parse(item) for item in items]
    if nodes is not None:
        known = list(nodes)
        unknown = sorted({e.node for e in out} - set(known))
        if unknown:
            raise ValueError(f"--expect: unknown node(s) {unknown}; the launch has {known}")
    return out
