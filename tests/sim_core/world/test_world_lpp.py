"""L++ grammars: parser errors, rewriting semantics, growth level, turtle vs a sequential turtle
(grammar files: tests/hil_bridge/files/test_world.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil_bridge.files.world import load_grammar, packaged_grammar
from sim_core.world.lpp import (
    GrammarError,
    branch_radii,
    expand,
    growth_level,
    interpret,
    parse_grammar,
)

SPECIES = ["tree4", "tree5", "tree6", "tree7"]


def test_tree4_rules_and_alternatives() -> None:
    g = load_grammar(packaged_grammar("tree4"))
    assert sorted(g.rules) == ["A", "B", "L"]
    assert [len(g.rules[k]) for k in "ABL"] == [4, 3, 3]
    assert "".join(c for c, _ in g.axiom) == "fffffffffA"
    # '>(30)' binds its parameter; '*(.3)' binds .3 (ignored by the turtle)
    assert (">", 30.0) in g.rules["A"][0]
    assert ("*", 0.3) in g.rules["L"][1]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("#c\n7\n15\n", r"<string>: expected 3 header numbers"),
        ("7\nabc\n60\nfA\n", r"<string>:2: expected a number \(default angle"),
        ("7\n15\n60\n", r"expected an axiom"),
        ("7\n15\n60\nfA\nA=f[f\n", r"<string>:5 \(rule 'A'\): unbalanced '\['"),
        ("7\n15\n60\nfA\nA=f]f\n", r"<string>:5 \(rule 'A'\): unbalanced '\]'"),
        ("7\n15\n60\nfA\nA=f(2\n", r"<string>:5 \(rule 'A'\): expected '\)'"),
        ("7\n15\n60\nfA\nA=f(x)\n", r"expected a number in the parameter of 'f', got 'x'"),
        ("7\n15\n60\nfA\nAB=f\n", r"<string>:5: expected a one-character rule symbol"),
        ("7\n15\n60\nfA\n+=f\n", r"not a turtle command, got '\+'"),
        ("7\n15\n60\nfA\nfB\n", r"<string>:5: expected a rule 'SYMBOL=replacement'"),
        ("2.5\n15\n60\nfA\n", r"iteration count must be an integer"),
        ("7\n15\n60\nfA\nA=fB(2)\nB=f\n", r"rule symbol 'B' cannot take a parameter"),
    ],
)
def test_parser_errors_name_line_and_expectation(text: str, match: str) -> None:
    with pytest.raises(GrammarError, match=match):
        parse_grammar(text)


def test_inline_header_comment_and_end_marker() -> None:
    g = parse_grammar("#x\n6\n37\n75 #thickness percentage\nfA\nA=f\n@\nthis is ignored\n")
    assert (g.iterations, g.thickness_pct) == (6, 75)


def _chars(seq: np.ndarray, table: list) -> str:
    return "".join(table[i][0] for i in seq)


def test_one_choice_per_symbol_per_iteration() -> None:
    g = parse_grammar("1\n15\n60\nAAAAAAAA\nA=x\nA=y\n")
    for seed in range(20):
        seq, table = expand(g, 1, np.random.default_rng(seed))
        assert _chars(seq, table) in ("x" * 8, "y" * 8)


def test_sequential_rewriting_in_key_order() -> None:
    # A inserts B, then B is rewritten in the same iteration (std::map order A < B)
    g = parse_grammar("1\n15\n60\nA\nA=fB\nB=gC\nC=h\n")
    seq, table = expand(g, 1, np.random.default_rng(0))
    assert _chars(seq, table) == "fgh"
    g2 = parse_grammar("1\n15\n60\nC\nA=x\nC=A\n")  # C inserts A after A was processed
    seq, table = expand(g2, 1, np.random.default_rng(0))
    assert _chars(seq, table) == "A"


def test_growth_level_distribution() -> None:
    rng = np.random.default_rng(5)
    levels = np.array([growth_level(7, rng) for _ in range(6000)])
    for lv, p in ((6, 0.33), (7, 0.34), (8, 0.33)):
        frac = np.mean(levels == lv)
        assert abs(frac - p) < 4 * math.sqrt(p * (1 - p) / levels.size)
    assert growth_level(0, rng) >= 0
    assert growth_level(7, rng, jitter=False) == 7


def _rodrigues(v: np.ndarray, k: np.ndarray, a: float) -> np.ndarray:
    k = k / np.linalg.norm(k)
    return v * math.cos(a) + np.cross(k, v) * math.sin(a) + k * np.dot(k, v) * (1 - math.cos(a))


def _reference_turtle(seq: np.ndarray, table: list, co: float) -> tuple[np.ndarray, np.ndarray]:
    """The seed's turtle (turtle.cpp) step by step: heading/right vectors, a state stack."""
    pos, d, r = np.zeros(3), np.array([0.0, 1, 0]), np.array([1.0, 0, 0])
    stack, leaves, dirs = [], [], []
    for i in seq:
        c, p = table[i]
        num = co if p is None or p == 1 else p
        if c in "+-":
            axis = np.cross(d, r)
            a = math.radians(-num if c == "+" else num)  # turnLeft(a) = turnRight(-a)
            d, r = _rodrigues(d, axis, a), _rodrigues(r, axis, a)
        elif c in "^&":
            d = _rodrigues(d, r, math.radians(num if c == "^" else -num))
        elif c in "/\\":
            r = _rodrigues(r, d, math.radians(num if c == "/" else -num))
        elif c in "fFgG":
            pos = pos + d * (1.0 if p is None else p)
        elif c == "[":
            stack.append((pos.copy(), d.copy(), r.copy()))
        elif c == "]":
            pos, d, r = stack.pop()
        elif c == "*":
            leaves.append(pos.copy())
            dirs.append(d.copy())
    return np.array(leaves), np.array(dirs)


@pytest.mark.parametrize("name", SPECIES)
def test_vectorised_turtle_matches_sequential_turtle(name: str) -> None:
    g = load_grammar(packaged_grammar(name))
    seq, table = expand(g, 3, np.random.default_rng(1))
    out = interpret(seq, table, g.default_angle_deg, np.random.default_rng(0), angle_noise=0.0)
    pos, dirs = _reference_turtle(seq, table, g.default_angle_deg)
    assert out.leaf_pos.shape == pos.shape and pos.shape[0] > 10
    np.testing.assert_allclose(out.leaf_pos, pos, atol=1e-9)
    np.testing.assert_allclose(out.leaf_dir, dirs, atol=1e-9)


def test_angle_noise_is_clipped_at_two_sigma() -> None:
    g = parse_grammar("0\n15\n60\n^(40)*\n")
    seq, table = expand(g, 0, np.random.default_rng(0))
    angles = []
    for seed in range(400):
        out = interpret(seq, table, g.default_angle_deg, np.random.default_rng(seed))
        angles.append(math.degrees(math.atan2(-out.leaf_dir[0, 2], out.leaf_dir[0, 1])))
    a = np.abs(np.array(angles))
    assert a.min() >= 40 * 0.8 - 1e-9 and a.max() <= 40 * 1.2 + 1e-9
    assert abs(a.mean() - 40) < 0.5 and 3.0 < a.std() < 4.5


def test_expansion_cap_fails_clearly() -> None:
    g = parse_grammar("30\n15\n60\nA\nA=AA\n")
    with pytest.raises(ValueError, match=r"exceeds \d+ symbols; lower the growth level"):
        expand(g, 30, np.random.default_rng(0))


def test_turtle_edge_cases_match_sequential_turtle() -> None:
    # leaves before any move, at the start of brackets, right after ']' and runs of one axis
    g = parse_grammar("0\n15\n60\n**[*[*]^*]*f[&*]*\\\\\\\\/f*[[[*]]]+(30)-(10)ff*\n")
    seq, table = expand(g, 0, np.random.default_rng(0))
    out = interpret(seq, table, g.default_angle_deg, np.random.default_rng(0), angle_noise=0.0)
    pos, dirs = _reference_turtle(seq, table, g.default_angle_deg)
    assert pos.shape == (11, 3)
    np.testing.assert_allclose(out.leaf_pos, pos, atol=1e-12)
    np.testing.assert_allclose(out.leaf_dir, dirs, atol=1e-12)


def test_branch_radius_commands_on_a_small_grammar() -> None:
    """Worked by hand from turtle.cpp: thickness 60 % of a unit segment, reduction 0.95."""
    g = parse_grammar("1\n15\n60\nA\nA=f[>(50)f=(10)ff%(50)f]<(100)f>f%f=f(2)\n")
    seq, table = expand(g, 1, np.random.default_rng(0))
    got = branch_radii(seq, table, g.default_angle_deg, g.thickness_pct,
                       np.random.default_rng(0), narrow_noise=0.0)
    expected = [
        (0.6, 0.57),      # f: base L*0.6, top *0.95
        (0.3, 0.285),     # [>(50) narrows by 50 %
        (0.1, 0.095),     # =(10) sets the thickness to 0.1
        (0.1, 0.095),
        (0.1, 0.05),      # %(50) sets the reduction to 0.5
        (1.2, 1.14),      # ] restores 0.6 and 0.95; <(100) doubles
        (1.02, 0.969),    # bare '>' narrows by the default angle, 15 %
        (1.02, 0.0102),   # bare '%' sets the reduction to 1/100
        (0.02, 0.0002),   # bare '=' sets the thickness to 1/100; f(2) doubles the radius
    ]
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_narrowing_is_drawn_per_command_and_clipped_at_two_sigma() -> None:
    g = parse_grammar("0\n15\n100\n" + ">(30)f" * 400 + "\n")
    seq, table = expand(g, 0, np.random.default_rng(0))
    base = branch_radii(seq, table, g.default_angle_deg, g.thickness_pct,
                        np.random.default_rng(3))[:, 0]
    factor = base[1:] / base[:-1]  # 1 - p'/100, p' ~ N(30, 3) clipped to [24, 36]
    assert factor.min() >= 0.64 - 1e-12 and factor.max() <= 0.76 + 1e-12
    assert abs(factor.mean() - 0.7) < 0.006 and 0.025 < factor.std() < 0.033
    # narrowing past 100 % gives radius 0, not a negative one
    g0 = parse_grammar("0\n15\n60\nf>(150)f\n")
    seq0, table0 = expand(g0, 0, np.random.default_rng(0))
    r0 = branch_radii(seq0, table0, 15.0, 60.0, np.random.default_rng(0), narrow_noise=0.0)
    np.testing.assert_array_equal(r0[1], [0.0, 0.0])


def _reference_radii(seq: np.ndarray, table: list, co: float, pct: float) -> np.ndarray:
    """The seed's thickness state (turtle.cpp, lplus.cpp) step by step, noise off."""
    thick, red, stack, out = pct / 100.0, 0.95, [], []
    for i in seq:
        c, p = table[i]
        num = co if p is None or p == 1 else p
        raw = 1.0 if p is None else p
        if c == "<":
            thick += thick * num / 100.0
        elif c == ">":
            thick -= thick * num / 100.0
        elif c == "=":
            thick = raw / 100.0
        elif c == "%":
            red = raw / 100.0
        elif c == "[":
            stack.append((thick, red))
        elif c == "]":
            thick, red = stack.pop()
        elif c in "Ff":
            out.append((raw * thick, raw * thick * red))
    return np.array(out)


@pytest.mark.parametrize("name", SPECIES)
def test_branch_radii_match_the_sequential_turtle(name: str) -> None:
    g = load_grammar(packaged_grammar(name))
    seq, table = expand(g, 4, np.random.default_rng(2))
    got = branch_radii(seq, table, g.default_angle_deg, g.thickness_pct,
                       np.random.default_rng(0), narrow_noise=0.0)
    want = _reference_radii(seq, table, g.default_angle_deg, g.thickness_pct)
    out = interpret(seq, table, g.default_angle_deg, np.random.default_rng(0))
    assert got.shape == want.shape == (out.seg_start.shape[0], 2) and got.shape[0] > 10
    assert np.unique(np.round(got[:, 0], 12)).size > 2  # the '>' commands do narrow
    np.testing.assert_allclose(got, want, rtol=1e-12)
