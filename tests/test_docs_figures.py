"""Every measured figure in the docs says where to get it again (issue 22, item 7).

The pages checked are README.md and docs/*.md (not docs/spec/, copied contracts, and not
BENCHMARKS.md, which ``python -m bench`` writes). The rule:

* A *figure* is a number followed by a unit of time (ns, µs, ms, s, min, h), size (B, kB, KiB,
  MB, MiB, GB), rate (Hz, kHz, MB/s, msg/s, frames/s, ...), share (%), length (mm, m) or a
  speed-up (``24x``, ``1.6×``). Inline code, code blocks, link targets and images are not read
  for figures (a command line's ``--duration 20`` is not a figure).
* A *block* is a paragraph, one list item, or a table together with the paragraph right before
  it (its caption).
* A block *reports a measurement* when it holds a word that says a value was observed rather
  than chosen (``MEASUREMENT``: measured, median, p50/p90/p99, took, CPU, load average, "this
  run", "on 2 cores", speed-up, throughput, benchmark ...). Protocol constants, rates of a
  configuration, defaults and model parameters carry units too (921600 baud, a 250 Hz tick, a
  0.4 s lag), but they stand in blocks that say what is configured, not what was observed, so
  they pass without a list of exceptions. Words that configuration text uses as often as
  measurements ("faster", "per second", "wall clock") are not markers.
* An approximate figure (``about 3 min``, ``~150 MB``, ``≈ 2 ms``) is an observation wherever
  it stands, a comment in a code block included: nobody configures "about 3 minutes".
* A block that reports a measurement and holds a figure, or that holds an approximate figure,
  must cite where the figure comes from: BENCHMARKS.md (best with its section,
  ``(BENCHMARKS.md, *Heading*)``), or a command one can rerun: ``python -m bench NAME``, an
  ``echoloop`` command, ``pytest``, ``make test|bench|demo``, or a test file ``tests/....py``.
* A page a bench section writes (its opening says "Written by ``python -m bench NAME``") is
  cited as a whole: every figure on it comes from that command.

A second check keeps the citations alive: each ``BENCHMARKS.md, *Heading*`` must name (the
start of) a heading BENCHMARKS.md has, since a regenerated BENCHMARKS.md keeps its headings and
changes its numbers: a page that cites a section stays true, a page that copies a number may not.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_NUMBER = r"(?<![\w.])\d+(?:[.,]\d+)*(?:e[-+−]?\d+)?"
_UNIT = (
    r"(?:%"
    r"|(?:ns|µs|μs|us|ms|s|min|h)(?![\w/²³])"
    r"|(?:B|kB|KB|KiB|MB|MiB|GB|GiB)(?![\w/])"
    r"|(?:[kMG]?B|KiB|MiB)/s(?!\w)"
    r"|(?:msgs?|messages|frames|echoes|pings|states|samples|calls)/s(?!\w)"
    r"|(?:k?Hz)(?!\w)"
    r"|(?:mm|µm|m)(?![\w/²³·])"
    r")"
)
#: a number with a unit of time, size, rate, share or length
FIGURE = re.compile(_NUMBER + r"\s?" + _UNIT)
#: a speed-up or a ratio: 24x, 1.6×
RATIO = re.compile(_NUMBER + r"[×x](?![\w\d])")
#: an approximate figure, a range allowed: about 3 min, ~1–2 µs, ≈ 0.5 ms
APPROX = re.compile(
    r"(?:\babout|\baround|\broughly|\bnearly|~|≈)\s*" + _NUMBER
    + r"(?:\s?[–-]\s?" + _NUMBER + r")?(?:\s?" + _UNIT + r"|[×x](?![\w\d]))"
)
#: words that say a value was observed, not chosen
MEASUREMENT = re.compile(
    r"\bmeasur\w*|\bmedians?\b|\bp50\b|\bp90\b|\bp99\b|\bpercentiles?\b|\bbenchmark\w*"
    r"|\btook\b|\bCPU\b|\bload average\b|\bthis machine\b|\bshared machine\b"
    r"|\b(?:this|that|one|the same|an earlier|earlier|two|three|four|every) runs?\b"
    r"|\bruns? of\b|\b\d+[- ](?:shared )?cores?\b|\bspeed-?ups?\b|\bthroughput\b",
    re.I,
)
#: where a figure can be had again
CITATION = re.compile(
    r"BENCHMARKS\.md|python -m bench\b|\bpytest\b|\bmake (?:test|bench|demo)\b"
    r"|\btests/[\w/.-]+\.py\b"
    r"|\becholoop (?:launch|replay|swarm|echo|scenario|forest|bus|topic|bag|mock|ardupilot)\b"
)
#: a citation of one section of BENCHMARKS.md
SECTION = re.compile(r"BENCHMARKS\.md,\s*\*([^*]+)\*")
#: the opening of a page a bench section writes
GENERATED = re.compile(r"Written by `python -m bench \w+`")


@dataclass(frozen=True)
class Block:
    """A paragraph, a list item or a table with its caption, as read for the rule."""

    page: str
    line: int
    text: str
    cite_text: str


def _raw_blocks(text: str) -> list[tuple[str, int, str]]:
    """(kind, first line, text) of each block: kind "p" prose or list item, "t" table, "c" a
    comment in a code block (its text after the prose before the code block), "x" a heading or
    code (never read, but it separates a table from the prose before it)."""
    out: list[tuple[str, int, str]] = []
    kind, start = "", 0  # the open block
    cur: list[str] = []
    fence = indented = False
    blank = True
    caption = ""  # the prose before an open code block

    def close() -> None:
        nonlocal kind, cur
        if cur:
            out.append((kind, start, "\n".join(cur)))
        kind, cur = "", []

    for no, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if stripped.startswith("```") or fence:
            if stripped.startswith("```"):
                close()
                if not fence:
                    caption = out[-1][2] if out and out[-1][0] == "p" else ""
                fence = not fence
                out.append(("x", no, ""))
            elif comment := re.search(r"(?:^|\s)#\s(.*)", line):
                out.append(("c", no, caption + "\n" + comment.group(1)))
            continue
        if not stripped:
            close()
            indented, blank = False, True
            continue
        if indented or (blank and line.startswith("    ")):
            if not indented:
                out.append(("x", no, ""))
            indented = True
            continue
        blank = False
        if stripped.startswith(("#", "<!--")):
            close()
            out.append(("x", no, ""))
            continue
        want = "t" if stripped.startswith("|") else "p"
        item = want == "p" and re.match(r"\s*(?:[-*]|\d+\.)\s", line) is not None
        if kind != want or item:
            close()
            kind, start = want, no
        cur.append(line)
    close()
    return out


def _blocks(page: str, text: str) -> list[Block]:
    """The blocks of a page; a table is cited by its own text and its caption's."""
    raw = _raw_blocks(text)
    blocks = []
    for i, (kind, start, body) in enumerate(raw):
        if kind == "x":
            continue
        if kind == "c":  # the comment is the last line, the caption before it
            blocks.append(Block(page, start, body.rsplit("\n", 1)[-1], body))
            continue
        caption = raw[i - 1][2] if kind == "t" and i and raw[i - 1][0] == "p" else ""
        blocks.append(Block(page, start, body, caption + "\n" + body))
    return blocks


def _prose(text: str) -> str:
    """The text a figure is read from: no inline code, images or link targets."""
    text = re.sub(r"`[^`]*`", " ", text)
    text = re.sub(r"!\[[^\]]*\]\([^)]*\)", " ", text)
    return re.sub(r"\]\([^)]*\)", "]", text)


def pages(root: Path) -> list[Path]:
    """The pages the rule applies to."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def untraced(root: Path) -> list[str]:
    """Blocks of the pages under ``root`` that quote a measured figure without a citation."""
    out: list[str] = []
    for path in pages(root):
        text = path.read_text(encoding="utf-8")
        opening = text.split("\n## ", 1)[0]
        if GENERATED.search(opening):
            continue
        for block in _blocks(path.relative_to(root).as_posix(), text):
            prose = _prose(block.text)
            cite = re.sub(r"\s+", " ", block.cite_text)  # a command may wrap across lines
            approx = APPROX.findall(prose)
            figures = FIGURE.findall(prose) + RATIO.findall(prose)
            measured = MEASUREMENT.search(_prose(cite)) is not None
            if (approx or (measured and figures)) and not CITATION.search(cite):
                shown = ", ".join(dict.fromkeys(m.strip() for m in (approx or figures)))
                out.append(f"{block.page}:{block.line}: {shown}")
    return out


def cited_sections(root: Path) -> list[str]:
    """``BENCHMARKS.md, *Heading*`` citations that name no heading of BENCHMARKS.md."""
    bench = (root / "BENCHMARKS.md").read_text(encoding="utf-8")
    headings = [h.strip() for h in re.findall(r"^#{2,4} (.+)$", bench, re.M)]
    bad = []
    for path in pages(root):
        text = re.sub(r"\s+", " ", path.read_text(encoding="utf-8"))
        for name in SECTION.findall(text):
            if not any(h.startswith(name.strip()) for h in headings):
                bad.append(f"{path.relative_to(root).as_posix()}: *{name}*")
    return bad


def test_every_measured_figure_cites_where_it_comes_from() -> None:
    bad = untraced(ROOT)
    assert not bad, (
        "figures that cite neither BENCHMARKS.md nor a command to rerun (cite the section, "
        "e.g. '(BENCHMARKS.md, *Test suite*)', or the command; or drop the number):\n"
        + "\n".join(bad)
    )


def test_cited_benchmark_sections_exist() -> None:
    bad = cited_sections(ROOT)
    assert not bad, "BENCHMARKS.md has no section of these names:\n" + "\n".join(bad)


def test_the_rule_catches_an_uncited_measurement_and_passes_a_cited_one(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "BENCHMARKS.md").write_text("# Benchmarks\n\n## Test suite: make test\n")
    readme = tmp_path / "README.md"
    readme.write_text("Set-up (about 3 min).\n\nThe tick is 4 ms (250 Hz), configured.\n")
    assert untraced(tmp_path) == ["README.md:1: about 3 min"]
    readme.write_text("Set-up (about 3 min; BENCHMARKS.md, *Test suite*).\n")
    assert untraced(tmp_path) == [] and cited_sections(tmp_path) == []
    (tmp_path / "docs" / "x.md").write_text(
        "Measured on 2 cores:\n\n| p50 |\n|---|\n| 0.32 ms |\n\nThe p99 was 8 ms.\n"
    )
    assert untraced(tmp_path) == ["docs/x.md:3: 0.32 ms", "docs/x.md:7: 8 ms"]
    readme.write_text("See (BENCHMARKS.md, *Bus load*).\n")
    assert cited_sections(tmp_path) == ["README.md: *Bus load*"]


def test_the_rule_reads_code_comments_and_trusts_generated_pages(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "BENCHMARKS.md").write_text("# Benchmarks\n")
    (tmp_path / "README.md").write_text(
        "Set-up:\n\n```\nmake test   # runs the suite (about 3 min)\necho --duration 20\n```\n"
    )
    (tmp_path / "docs" / "gen.md").write_text(
        "# Parity\n\nWritten by `python -m bench parity`.\n\n## A\n\nIt took 5 ms in this run.\n"
    )
    assert untraced(tmp_path) == ["README.md:4: about 3 min"]
