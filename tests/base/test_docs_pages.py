"""Every page under docs/ is a reference a user can read: short, with today's figures only.

Two rules, checked on every ``docs/**/*.md`` page except the generated ``docs/cli.md`` and the
history kept under ``docs/findings/``:

1. **At most 300 lines** (``MAX_LINES``). How a figure came about (rounds, before/after runs,
   dead ends) belongs in a findings page, not in the reference.

2. **One measurement per figure in a table cell.** A cell of a Markdown table (a line starting
   with ``|``; the header and ``|---|`` rows are skipped) may hold at most one *measurement* per
   unit. A measurement is a number written with a unit right after it: ``ms``, ``s``, ``CPU-s``,
   ``min``, ``MB``, ``GB``, ``GiB``, ``KB``/``kB``, ``%``, ``pp`` or a ratio ``x`` (``1.5x``).
   So ``19.4 ms`` is one, and so is ``19.4 / 36.5 ms``: a pair of figures read together (p50 / p95,
   wall / CPU) written with the unit once is one measurement. Not measurements:

   - a **range**, ``6-26 ms`` or ``6 - 26 ms`` or ``6–26 ms`` (one figure that varies: one
     measurement);
   - a **threshold**, a number after ``<=``, ``>=``, ``<``, ``>``, ``≤``, ``≥``, ``under``,
     ``over``, ``at most``, ``at least`` or ``up to`` (a target or a limit, not something measured);
   - numbers without a unit (counts, hours of memory such as ``1,000 h``, ids, commits).

   A cell that says ``29.8 ms wall, 36.8 ms CPU`` or ``40.9 ms (was 43.2 ms)`` holds two
   measurements with the same unit and fails: put the second one in a column of its own, or move
   the history to docs/findings/. The targets table of docs/performance.md before issue 32 (one
   cell held six rounds of one figure) fails this rule; ``test_the_rules_catch_a_history_in_a_cell``
   keeps an excerpt of it.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
MAX_LINES = 300
UNITS = r"(?:CPU-s|ms|min|s|MB|GB|GiB|KB|kB|%|pp|x)"
NUMBER = r"\d[\d,]*(?:\.\d+)?"
# a range "6-26", "6 - 26", "6–26", "6 to 26" reads as its last number; a pair "19.4 / 36.5" too
_RANGE = re.compile(rf"{NUMBER}\s*(?:-|–|—|to)\s*(?={NUMBER})")
_PAIR = re.compile(rf"{NUMBER}\s*/\s*(?={NUMBER})")
_THRESHOLD = re.compile(rf"(?:<=|>=|≤|≥|<|>|\bunder|\bover|\bat most|\bat least|\bup to)\s*{NUMBER}\s*{UNITS}?")
_MEASURE = re.compile(rf"(?<![\w.,]){NUMBER}\s?({UNITS})(?![\w-])")


def reference_pages() -> list[Path]:
    """Every docs page a user reads as reference: not the generated CLI page, not findings."""
    return [p for p in sorted(DOCS.rglob("*.md"))
            if p != DOCS / "cli.md" and DOCS / "findings" not in p.parents]


def measurements(cell: str) -> list[str]:
    """The units of the measurements in one table cell, one entry per measurement (rule 2)."""
    text = re.sub(r"`[^`]*`", " ", cell)          # code: commands and names, not figures
    text = _THRESHOLD.sub(" ", text)
    text = _RANGE.sub("", text)
    text = _PAIR.sub("", text)
    return [m.group(1) for m in _MEASURE.finditer(text)]


def table_cells(text: str) -> list[tuple[int, str]]:
    """(line number, cell) for every body cell of every Markdown table of a page."""
    out, fenced = [], False
    for n, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
        if fenced or not line.startswith("|"):
            continue
        cells = line.strip().strip("|").split("|")
        if all(re.fullmatch(r"\s*:?-+:?\s*", c) for c in cells):
            continue
        out.extend((n, c.strip()) for c in cells)
    return out


def repeated_figures(text: str) -> list[str]:
    """'line N: cell' for every cell holding two measurements with the same unit."""
    bad = []
    for n, cell in table_cells(text):
        units = measurements(cell)
        if len(units) != len(set(units)):
            bad.append(f"line {n}: {cell[:160]}")
    return bad


def test_there_are_reference_pages_and_findings():
    pages = reference_pages()
    assert DOCS / "performance.md" in pages and DOCS / "scale.md" in pages
    assert (DOCS / "findings" / "README.md").exists()


@pytest.mark.parametrize("page", reference_pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_a_reference_page_is_at_most_300_lines(page):
    lines = len(page.read_text().splitlines())
    assert lines <= MAX_LINES, (f"{page.relative_to(ROOT)} has {lines} lines (at most {MAX_LINES}): keep the "
                                "reference, move history to docs/findings/")


@pytest.mark.parametrize("page", reference_pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_a_table_cell_holds_one_measurement_of_a_figure(page):
    bad = repeated_figures(page.read_text())
    assert not bad, (f"{page.relative_to(ROOT)}: a table cell holds more than one measurement of a figure "
                     "(one figure per cell; history goes to docs/findings/):\n" + "\n".join(bad))


def test_every_finding_is_in_the_findings_index():
    index = (DOCS / "findings" / "README.md").read_text()
    for page in sorted((DOCS / "findings").glob("*.md")):
        if page.name != "README.md":
            assert f"({page.name})" in index, f"docs/findings/{page.name} is not listed in docs/findings/README.md"


def test_the_rules_catch_a_history_in_a_cell():
    # an excerpt of the targets table of docs/performance.md before issue 32
    old = ("| target | command | measured | |\n|---|---|---|---|\n"
           "| 1,000 h: tool p95 <= 50 ms and open <= 2 s | the same | seventh measurement: `search` "
           "**29.8 / 32.2 ms wall, 36.8 / 41.6 CPU** (`e91d50a` 66.5 / 51.4 wall), the six others 6-21 ms; "
           "open 0.76-0.92 s; sixth measurement: CPU p50 / p95 43.2 / 55.0 -> **40.9 / 47.2** ms | met |\n")
    assert repeated_figures(old)
    assert measurements("29.8 ms wall, 36.8 ms CPU") == ["ms", "ms"]
    assert measurements("40.9 ms (was 43.2 ms)") == ["ms", "ms"]
    # one measurement each: a range, a pair with its unit once, a target beside a figure, units apart
    assert measurements("6-26 ms") == ["ms"]
    assert measurements("6 - 26 ms") == ["ms"]
    assert measurements("19.4 / 36.5 ms") == ["ms"]
    assert measurements("p50 <= 20 ms, p95 <= 50 ms") == []
    assert measurements("at most 32 MB handed back (the MCP tool: at most 4 MB)") == []
    assert measurements("0.865 s, 790 MB, 1.18x") == ["s", "MB", "x"]
    assert measurements("`memora perf scale --sizes 10,100,1000` at 1,000 h, load 0.6") == []
    assert not repeated_figures("| a | b |\n|---|---|\n| 2,967 MB | 830 MB |\n")

