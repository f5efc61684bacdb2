"""Seed 001 stochastic L++ grammars: parser, rewriting and a vectorised turtle (spec §2B).

Text format (``*.l++`` files, FG ``lsystem.cpp``; reading them is ``hil_bridge.files.world``):
``#`` starts a comment line (a ``#`` after a header number starts an inline comment); then three
numbers — iterations, default angle (degrees), thickness percentage; then the axiom; then rules
``S=replacement`` (several rules for one symbol are a random choice); ``@`` ends the text. A
command takes a parameter when ``(`` follows it immediately; a parameter of exactly 1 (or none)
means "the default angle" for the angle and thickness commands.

Semantics (spec §2B.3-2B.5), all randomness from the ``rng`` argument:

* one alternative is drawn per symbol per iteration and replaces every occurrence of that symbol;
  symbols are rewritten one after the other in sorted order on the string as it stands
  (sequential, not parallel, rewriting);
* growth level: iterations − 1 / + 1 with probabilities 0.33 / 0.33, once per tree;
* ``&``, ``^``, ``\\``, ``/`` angles are N(a, 0.1 a) clipped at ±2σ;
* ``*`` is a leaf kept with probability 0.5; ``|`` turns by 180° (the seed's 3.14° is a units bug);
* ``<`` ``>`` ``=`` ``%`` change the branch thickness and reduction (:func:`branch_radii`);
* the turtle frame (position, heading, right vector) starts fresh for every tree.

The turtle is evaluated without a Python loop over commands: every command is a rigid transform
in the turtle's local frame, so each bracket level is a segmented prefix product (a log-step scan)
and nesting is resolved level by level.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Grammar",
    "GrammarError",
    "TurtleResult",
    "branch_radii",
    "expand",
    "interpret",
    "parse_grammar",
]

F64 = NDArray[np.float64]

#: turtle commands understood by :func:`interpret` (all other characters are no-ops)
COMMANDS = frozenset("+-&^<>\\/%=|*FfGg[]")

#: upper bound on the number of symbols of an expanded string (guards runaway grammars)
MAX_SYMBOLS = 4_000_000


class GrammarError(ValueError):
    """A malformed L++ grammar; the message names the file, the line and what was expected."""


@dataclass(frozen=True)
class Grammar:
    """A parsed L++ grammar.

    Attributes:
        iterations: nominal growth level (rewriting iterations).
        default_angle_deg: angle used by commands without a parameter (or with parameter 1).
        thickness_pct: initial branch thickness in percent of the segment length.
        axiom: token tuple ``((char, param | None), ...)``.
        rules: symbol -> tuple of alternatives (each a token tuple); the symbols sorted.
        source: file name (or ``"<string>"``) for messages.
    """

    iterations: int
    default_angle_deg: float
    thickness_pct: float
    axiom: tuple[tuple[str, float | None], ...]
    rules: dict[str, tuple[tuple[tuple[str, float | None], ...], ...]]
    source: str = "<string>"


def _tokenize(text: str, where: str) -> list[tuple[str, float | None]]:
    """Split ``text`` into (command, parameter) with the seed's rule: ``X(p)`` binds p to X."""
    out: list[tuple[str, float | None]] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if i + 1 < n and text[i + 1] == "(":
            close = text.find(")", i + 2)
            if close < 0:
                raise GrammarError(f"{where}: expected ')' to close the parameter of {c!r}")
            raw = text[i + 2 : close]
            try:
                value = float(raw)
            except ValueError:
                raise GrammarError(
                    f"{where}: expected a number in the parameter of {c!r}, got {raw!r}"
                ) from None
            if not math.isfinite(value):
                raise GrammarError(f"{where}: parameter of {c!r} must be finite, got {raw!r}")
            out.append((c, value))
            i = close + 1
        else:
            out.append((c, None))
            i += 1
    depth = 0
    for c, _ in out:
        depth += (c == "[") - (c == "]")
        if depth < 0:
            raise GrammarError(f"{where}: unbalanced ']' (no matching '[')")
    if depth:
        raise GrammarError(f"{where}: unbalanced '[' ({depth} not closed)")
    return out


def parse_grammar(text: str, source: str = "<string>") -> Grammar:
    """Parse the text of an ``.l++`` file; raise :class:`GrammarError` naming ``source:line``."""
    numbers: list[float] = []
    names = ("iteration count", "default angle in degrees", "thickness percentage")
    axiom: tuple[tuple[str, float | None], ...] | None = None
    rules: dict[str, list[tuple[tuple[str, float | None], ...]]] = {}
    rule_lines: dict[str, int] = {}
    for lineno, raw_line in enumerate(text.splitlines(), start=1):
        where = f"{source}:{lineno}"
        line = raw_line.lstrip()
        if not line.strip() or line.startswith("#"):
            continue
        if line.startswith("@"):
            break
        if len(numbers) < 3:
            for word in line.split("#", 1)[0].split():
                if len(numbers) == 3:
                    raise GrammarError(f"{where}: expected at most 3 header numbers, got {word!r}")
                try:
                    value = float(word)
                except ValueError:
                    raise GrammarError(
                        f"{where}: expected a number ({names[len(numbers)]}), got {word!r}"
                    ) from None
                if not math.isfinite(value):
                    raise GrammarError(f"{where}: {names[len(numbers)]} must be finite")
                numbers.append(value)
            continue
        body = line.rstrip("\r\n")
        if "=" not in body:
            if axiom is not None:
                raise GrammarError(
                    f"{where}: expected a rule 'SYMBOL=replacement' (the axiom is already "
                    f"given), got {body.strip()!r}"
                )
            axiom = tuple(_tokenize(body.strip(), where))
            if not axiom:
                raise GrammarError(f"{where}: expected a non-empty axiom")
            continue
        key, _, repl = body.partition("=")
        key = key.strip()
        if len(key) != 1 or key in COMMANDS or key in "()":
            raise GrammarError(
                f"{where}: expected a one-character rule symbol that is not a turtle command, "
                f"got {key!r}"
            )
        if repl.startswith("("):
            raise GrammarError(f"{where}: replacement of {key!r} must not start with '('")
        rules.setdefault(key, []).append(tuple(_tokenize(repl, f"{where} (rule {key!r})")))
        rule_lines.setdefault(key, lineno)
    if len(numbers) < 3:
        raise GrammarError(
            f"{source}: expected 3 header numbers (iterations, default angle, thickness %), "
            f"found {len(numbers)}"
        )
    if axiom is None:
        raise GrammarError(f"{source}: expected an axiom line after the 3 header numbers")
    iterations = numbers[0]
    if iterations != int(iterations) or iterations < 0:
        raise GrammarError(f"{source}: iteration count must be an integer >= 0, got {iterations}")
    for key, alts in rules.items():
        for alt in alts:
            for c, p in alt:
                if c in rules and p is not None:
                    raise GrammarError(
                        f"{source}:{rule_lines[key]}: rule symbol {c!r} cannot take a parameter"
                    )
    for c, p in axiom:
        if c in rules and p is not None:
            raise GrammarError(f"{source}: rule symbol {c!r} in the axiom cannot take a parameter")
    return Grammar(
        iterations=int(iterations),
        default_angle_deg=numbers[1],
        thickness_pct=numbers[2],
        axiom=axiom,
        rules={k: tuple(rules[k]) for k in sorted(rules)},
        source=source,
    )


# --- rewriting -------------------------------------------------------------------------------


class _Table:
    """Interns (char, param) tokens to int ids so strings become int arrays."""

    def __init__(self) -> None:
        self.ids: dict[tuple[str, float | None], int] = {}
        self.tokens: list[tuple[str, float | None]] = []

    def encode(self, seq: tuple[tuple[str, float | None], ...]) -> NDArray[np.int32]:
        out = np.empty(len(seq), dtype=np.int32)
        for i, tok in enumerate(seq):
            j = self.ids.get(tok)
            if j is None:
                j = len(self.tokens)
                self.ids[tok] = j
                self.tokens.append(tok)
            out[i] = j
        return out


def _replace(seq: NDArray[np.int32], key: int, alt: NDArray[np.int32]) -> NDArray[np.int32]:
    mask = seq == key
    if not mask.any():
        return seq
    if alt.size == 0:
        return seq[~mask]
    counts = np.where(mask, alt.size, 1)
    total = int(counts.sum())
    if total > MAX_SYMBOLS:
        raise ValueError(
            f"L++ expansion exceeds {MAX_SYMBOLS} symbols; lower the growth level"
        )
    starts = np.cumsum(counts) - counts
    out = np.repeat(seq, counts)
    hit = starts[mask]
    out[(hit[:, None] + np.arange(alt.size)[None, :]).ravel()] = np.tile(alt, hit.size)
    return out


def growth_level(nominal: int, rng: np.random.Generator, *, jitter: bool = True) -> int:
    """The seed's discrete growth level: nominal − 1 (p 0.33), + 1 (p 0.33), else nominal."""
    if not jitter:
        return nominal
    r = rng.random()
    if r <= 0.33:
        return max(nominal - 1, 0)
    if r >= 0.67:
        return nominal + 1
    return nominal


def expand(
    grammar: Grammar, iterations: int, rng: np.random.Generator
) -> tuple[NDArray[np.int32], list[tuple[str, float | None]]]:
    """Rewrite the axiom ``iterations`` times; return (token ids, id -> (char, param) table)."""
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0, got {iterations}")
    table = _Table()
    seq = table.encode(grammar.axiom)
    compiled = {
        table.encode(((k, None),))[0]: [table.encode(a) for a in alts]
        for k, alts in grammar.rules.items()
    }
    for _ in range(iterations):
        for key_id, alts in compiled.items():
            choice = int(rng.integers(len(alts))) if len(alts) > 1 else 0
            seq = _replace(seq, int(key_id), alts[choice])
    return seq, table.tokens


# --- turtle ----------------------------------------------------------------------------------

_OPEN, _CLOSE, _ROT, _MOVE, _LEAF, _THICK = 1, 2, 3, 4, 5, 6

#: tokens per vectorised block in the scan (bounds the temporaries to a few MB)
_CHUNK = 32768


@dataclass(frozen=True, eq=False)
class TurtleResult:
    """Turtle output in grammar units, L++ frame (y up).

    Attributes:
        leaf_pos: (K, 3) positions of the executed ``*`` commands (before the keep draw).
        leaf_dir: (K, 3) unit turtle headings at those commands.
        seg_start, seg_end: (S, 3) start/end of the drawn ``F``/``f`` segments.
    """

    leaf_pos: F64
    leaf_dir: F64
    seg_start: F64
    seg_end: F64


def _qmul(a: F64, b: F64) -> F64:
    """Hamilton products of quaternions stored as rows ``(4, N)`` = (w, x, y, z)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def _qrot(q: F64, v: F64) -> F64:
    """Rotate vectors ``v (3, N)`` by unit quaternions ``q (4, N)``."""
    w, x, y, z = q
    vx, vy, vz = v
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return np.stack(
        [
            vx + w * tx + (y * tz - z * ty),
            vy + w * ty + (z * tx - x * tz),
            vz + w * tz + (x * ty - y * tx),
        ]
    )


def _scopes(is_open: NDArray[np.bool_], is_close: NDArray[np.bool_]
            ) -> tuple[NDArray[np.int64], list[NDArray[np.int64]]]:
    """Bracket scopes of a token sequence: for every token the index of the '[' that opens its
    level (-1 at the top), and the tokens that are not ']' grouped by bracket depth."""
    n = is_open.size
    step = is_open.astype(np.int64) - is_close
    level = np.cumsum(step) - step  # bracket depth before each token
    pos = np.arange(n)
    seg = np.full(n, -1, dtype=np.int64)
    body = ~is_close
    by_level = pos[body][np.argsort(level[body], kind="stable")]
    bounds = np.searchsorted(level[by_level], np.arange(int(level.max()) + 2 if n else 1))
    groups = [by_level[bounds[d] : bounds[d + 1]] for d in range(bounds.size - 1)]
    for d in range(1, len(groups)):
        at = groups[d]
        parents = groups[d - 1]
        opens = parents[is_open[parents]]
        if at.size:
            seg[at] = opens[np.searchsorted(opens, at, side="right") - 1]
    return seg, groups


Compose = Callable[[F64, F64], F64]


def _compose_frames(prev: F64, cur: F64) -> F64:
    """Turtle frames as rows (quaternion (4,), translation (3,)): ``prev`` then ``cur``."""
    out = np.empty_like(cur)
    out[4:] = prev[4:] + _qrot(prev[:4], cur[4:])
    out[:4] = _qmul(prev[:4], cur[:4])
    return out


def _nested_scan(
    state: F64,
    seg: NDArray[np.int64],
    groups: list[NDArray[np.int64]],
    order: NDArray[np.int64],
    use: NDArray[np.bool_],
    compose: Compose,
) -> None:
    """In place: ``state[:, i]`` (a local transform per token, rows R) becomes the composition,
    in command order, of every transform visible at token i (those of its own bracket level up
    to i, after those of the levels enclosing it up to their '[').

    ``order``: the tokens taking part (``use``), sorted by scope (``seg``) keeping command order.
    A segmented inclusive scan (log-step) inside every scope, then nesting resolved level by
    level: world(i) = world('[' opening i's level) then prefix(i).
    """
    st = state[:, order]
    sseg = seg[order]
    first = np.ones(order.size, dtype=bool)
    first[1:] = sseg[1:] != sseg[:-1]
    rank = np.arange(order.size) - np.maximum.accumulate(np.where(first, np.arange(order.size), 0))
    k = 1
    while order.size and k <= int(rank.max()):
        active = np.nonzero(rank >= k)[0]
        # chunks from the top down: a chunk reads only lower indices, which are still unchanged
        for blk in range((active.size - 1) // _CHUNK, -1, -1):
            i = active[blk * _CHUNK : (blk + 1) * _CHUNK]
            st[:, i] = compose(st[:, i - k], st[:, i])
        k *= 2
    state[:, order] = st
    del st
    for level_all in groups[1:]:
        level_tokens = level_all[use[level_all]]
        for blk in range(0, level_tokens.size, _CHUNK):
            at = level_tokens[blk : blk + _CHUNK]
            state[:, at] = compose(state[:, seg[at]], state[:, at])


def interpret(
    seq: NDArray[np.int32],
    table: list[tuple[str, float | None]],
    default_angle_deg: float,
    rng: np.random.Generator,
    *,
    angle_noise: float = 0.1,
) -> TurtleResult:
    """Run the turtle over the token ids ``seq`` (frame reset: heading +y, right +x, at 0)."""
    # per table entry: kind, local rotation axis, nominal value
    kinds = np.zeros(len(table), dtype=np.int8)
    axes = np.zeros(len(table), dtype=np.int8)
    values = np.zeros(len(table))
    noisy = np.zeros(len(table), dtype=bool)
    for j, (c, p) in enumerate(table):
        num = default_angle_deg if p is None or p == 1 else p
        if c == "[":
            kinds[j] = _OPEN
        elif c == "]":
            kinds[j] = _CLOSE
        elif c in "+-&^\\/|":
            kinds[j] = _ROT
            axes[j] = {"+": 2, "-": 2, "|": 2, "&": 0, "^": 0, "\\": 1, "/": 1}[c]
            sign = 1.0 if c in "+^/" else -1.0
            values[j] = math.pi if c == "|" else sign * math.radians(num)
            noisy[j] = c in "&^\\/"
        elif c in "FfGg":
            kinds[j] = _MOVE
            values[j] = 1.0 if p is None else p
        elif c == "*":
            kinds[j] = _LEAF
    tok_kind = kinds[seq]
    ids = seq[tok_kind > 0]
    kind = kinds[ids]
    axis = axes[ids]
    val = values[ids]  # signed angle (rad) of a rotation, length of a move
    jitter = noisy[ids]
    if jitter.any():
        z = np.clip(rng.standard_normal(int(jitter.sum())), -2.0, 2.0)
        val[jitter] *= 1.0 + angle_noise * z
    is_draw = np.asarray([c in "Ff" for c, _ in table], dtype=bool)[ids]
    # consecutive rotations about the same local axis compose by adding angles (exact)
    rot = kind == _ROT
    merge = np.zeros(kind.size, dtype=bool)
    merge[1:] = rot[1:] & rot[:-1] & (axis[1:] == axis[:-1])
    if merge.any():
        starts = np.flatnonzero(~merge)
        val = np.add.reduceat(val, starts)
        kind, axis, is_draw, rot = kind[starts], axis[starts], is_draw[starts], rot[starts]
    n = kind.size
    is_open = kind == _OPEN
    is_close = kind == _CLOSE

    # local transforms as rows: unit quaternion (0-3) and translation (4-6) in the turtle frame
    # (columns right, heading, right × heading); every command right-multiplies the frame
    frames = np.zeros((7, n))
    frames[0] = 1.0
    ridx = np.flatnonzero(rot)
    frames[0, ridx] = np.cos(val[ridx] / 2.0)
    frames[1 + axis[ridx], ridx] = np.sin(val[ridx] / 2.0)
    mv = kind == _MOVE
    frames[5, mv] = val[mv]

    seg, groups = _scopes(is_open, is_close)

    # a leaf changes nothing: it takes the state of the last non-leaf token before it in its
    # bracket level, or of the '[' opening the level (-1: the start state); leaves skip the scan
    leaf = kind == _LEAF
    pos = np.arange(n)
    members = pos[~is_close]
    order_all = members[np.argsort(seg[members], kind="stable")]
    seg_sorted = seg[order_all]
    idx = np.arange(order_all.size)
    starts_seg = np.ones(order_all.size, dtype=bool)
    starts_seg[1:] = seg_sorted[1:] != seg_sorted[:-1]
    head_all = np.maximum.accumulate(np.where(starts_seg, idx, 0))
    leaf_sorted = leaf[order_all]
    last_state = np.maximum.accumulate(np.where(leaf_sorted, -1, idx))[leaf_sorted]
    within = last_state >= head_all[leaf_sorted]
    leaf_ref = np.where(
        within, order_all[np.maximum(last_state, 0)], seg_sorted[leaf_sorted]
    )[np.argsort(order_all[leaf_sorted])]  # back to command order

    draw = is_draw & mv
    draw_len = frames[5, draw].copy()
    _nested_scan(frames, seg, groups, order_all[~leaf_sorted], ~leaf, _compose_frames)
    Wq, Wt = frames[:4], frames[4:]

    yhat = np.array([[0.0], [1.0], [0.0]])
    # column -1 of the extended arrays is the start state (identity at the origin)
    leaf_q = np.concatenate([Wq, [[1.0], [0.0], [0.0], [0.0]]], axis=1)[:, leaf_ref]
    leaf_t = np.concatenate([Wt, np.zeros((3, 1))], axis=1)[:, leaf_ref]
    leaf_dir = _qrot(leaf_q, np.broadcast_to(yhat, (3, leaf_ref.size))).T
    heading = _qrot(Wq[:, draw], np.broadcast_to(yhat, (3, int(draw.sum())))).T
    seg_end = Wt[:, draw].T
    seg_start = seg_end - heading * draw_len[:, None]
    return TurtleResult(
        leaf_pos=leaf_t.T.copy(),
        leaf_dir=leaf_dir / np.linalg.norm(leaf_dir, axis=1, keepdims=True),
        seg_start=seg_start,
        seg_end=seg_end,
    )


#: the turtle's initial reduction, the ratio of a segment's top to base radius (turtle.cpp)
REDUCTION = 0.95


def _compose_affine(prev: F64, cur: F64) -> F64:
    """Pairs of affine maps x -> a x + b as rows (a, b, c, d) (thickness, reduction): ``prev``
    then ``cur``."""
    out = np.empty_like(cur)
    out[0::2] = cur[0::2] * prev[0::2]
    out[1::2] = cur[0::2] * prev[1::2] + cur[1::2]
    return out


def branch_radii(
    seq: NDArray[np.int32],
    table: list[tuple[str, float | None]],
    default_angle_deg: float,
    thickness_pct: float,
    rng: np.random.Generator,
    *,
    narrow_noise: float = 0.1,
) -> F64:
    """Base and top radius of every drawn segment, (S, 2), grammar units, the seed's way.

    The segments are the ``F``/``f`` commands of ``seq`` in order (those of
    :func:`interpret`). As in the seed's turtle (``lplus.cpp``, ``turtle.cpp``): the thickness
    starts at ``thickness_pct``/100 and the reduction at 0.95; ``<(p)`` multiplies the thickness
    by 1 + p/100, ``>(p)`` by 1 − p'/100 with p' ~ N(p, (``narrow_noise``·p)²) clipped at ±2σ
    (drawn from ``rng``), ``=(p)`` sets it to p/100 and ``%(p)`` the reduction to p/100; ``[``
    and ``]`` save and restore both. For ``<`` and ``>`` a parameter of 1 or none means the
    default angle (the seed's rule for every parametric command), for ``=`` and ``%`` it is 1.
    A segment of length L has base radius L·thickness and top radius base·reduction; the
    thickness never shrinks by itself. A thickness narrowed below 0 gives radius 0.
    """
    kinds = np.zeros(len(table), dtype=np.int8)
    local = np.tile(np.array([[1.0], [0.0], [1.0], [0.0]]), (1, len(table)))
    noisy = np.zeros(len(table), dtype=bool)
    length = np.zeros(len(table))
    for j, (c, p) in enumerate(table):
        num = default_angle_deg if p is None or p == 1 else p
        raw = 1.0 if p is None else p
        if c == "[":
            kinds[j] = _OPEN
        elif c == "]":
            kinds[j] = _CLOSE
        elif c in "Ff":
            kinds[j] = _MOVE
            length[j] = raw
        elif c in "<>%=":
            kinds[j] = _THICK
            if c == "<":
                local[0, j] = 1.0 + num / 100.0
            elif c == ">":
                local[0, j] = num  # the narrowing in percent, drawn per command below
                noisy[j] = True
            elif c == "=":
                local[:2, j] = 0.0, raw / 100.0
            else:
                local[2:, j] = 0.0, raw / 100.0
    ids = seq[kinds[seq] > 0]
    kind = kinds[ids]
    state = local[:, ids]
    jitter = noisy[ids]
    if jitter.any():
        pct = state[0, jitter]
        pct *= 1.0 + narrow_noise * np.clip(rng.standard_normal(pct.size), -2.0, 2.0)
        state[0, jitter] = 1.0 - pct / 100.0
    is_open, is_close = kind == _OPEN, kind == _CLOSE
    seg, groups = _scopes(is_open, is_close)
    members = np.flatnonzero(~is_close)
    order = members[np.argsort(seg[members], kind="stable")]
    _nested_scan(state, seg, groups, order, ~is_close, _compose_affine)
    draw = kind == _MOVE
    a, b, c, d = state[:, draw]
    base = np.maximum(length[ids[draw]] * (a * (thickness_pct / 100.0) + b), 0.0)
    return np.stack([base, base * (c * REDUCTION + d)], axis=1)

