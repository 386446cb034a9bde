"""report.html reads in an ordinary browser window: its figures fit a 1,400 px window, measured in a
real headless Chromium after the images have loaded (the figures are the ones `memora bench report`
draws: RGP per split, the reliability diagram, compression and the editor's decisions)."""

from __future__ import annotations

import re

import pytest

from memora_graph.bench.report import _figures, render_html
from support.browser import CHROMIUM, NO_CHROMIUM, dump_dom, elements

WINDOW = (1400, 1000)
CONDITIONS = {"no_memory": "Parametric", "flat_1d_raw": "Flat-1D (raw)", "flat_1d_edited": "Flat-1D (processed)",
              "graph_2d_raw": "Graph-2D (raw)", "graph_2d_edited": "Graph-2D (processed)",
              "memora_episodic": "MEMORA-Episodic", "memora_full": "MEMORA"}

# After load, the page records how wide it is and where each figure ends, on <html> (read from the DOM)
MEASURE = """<script>
window.addEventListener("load", () => {
  const root = document.documentElement, imgs = [...document.images];
  root.dataset.viewport = String(window.innerWidth);
  root.dataset.scrollWidth = String(root.scrollWidth);
  root.dataset.loaded = String(imgs.filter(i => i.complete && i.naturalWidth > 0).length);
  root.dataset.figureRight = String(Math.max(...imgs.map(i => i.getBoundingClientRect().right)));
  const row = imgs.length ? imgs[0].parentElement : null;
  root.dataset.rowScrollWidth = row ? String(row.scrollWidth) : "";
  root.dataset.rowClientWidth = row ? String(row.clientWidth) : "";
});
</script>"""


def _report_with_every_figure(out):
    """A report whose figures are drawn by the report's own code from a hand-made report dict
    (both planning splits, MEMORA's calibration, memory formation), so all four are there."""
    rgp = [.159, .327, .318, .405, .421, .451, .548]
    planning = {c: {"label": label, "replay": {"rgp": r}, "generalize": {"rgp": r - .05}}
                for (c, label), r in zip(CONDITIONS.items(), rgp)}
    bins = [{"confidence": c / 10 + .05, "accuracy": c / 10, "n": 10 + c} for c in range(3, 10)]
    cal = {"memora_full": {"fitted": {"n": 548, "ece": .036, "reliability": bins},
                           "held_out": {"n": 198, "ece": .064, "reliability": bins}}}
    series = {"without_editor": list(range(1, 200)), "with_editor": [1 + i // 20 for i in range(199)]}
    rep = {"planning": planning,
           "planning_vs_best_baseline": {s: {"delta": .127, "best_baseline": "graph_2d_edited", "best_baseline_rgp": .421}
                                         for s in ("replay", "generalize")},
           "eam_qa": {"calibration": {"conditions": cal}},
           "memory_formation": {"participants": {"P01": series, "P02": series}, "median_compression": 35.3,
                                "decisions": {"NOOP": 60, "UPDATE": 30, "ADD": 9, "DELETE": 1},
                                "decision_share": {"NOOP": .6, "UPDATE": .3, "ADD": .09, "DELETE": .01},
                                "compression": {"P01": 35.3, "P02": 35.3}}}
    figures = _figures(rep, out)
    assert {p.name for p in figures} == {"rgp.png", "reliability.png", "compression.png", "decisions.png"}
    md = "\n".join(["# MEMORA-Bench report", "", "## Figures", ""] + [f"![{p.name}]({p.name})" for p in figures])
    return figures, md


@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason=NO_CHROMIUM)
def test_the_figure_row_fits_a_1400_px_window(tmp_path):
    figures, md = _report_with_every_figure(tmp_path)
    html = render_html(md)
    assert all(f'src="{p.name}"' in html for p in figures)
    page = tmp_path / "report.html"
    page.write_text(html.replace("</body>", MEASURE + "</body>"))
    dom = dump_dom(page, size=WINDOW, settle_ms=5000)
    root = elements(dom, "html")[0]
    assert int(root["data-loaded"]) == len(figures), "every figure loaded"
    viewport = int(root["data-viewport"])
    assert viewport <= WINDOW[0]
    assert int(root["data-scroll-width"]) <= viewport, "the page scrolls sideways"
    assert float(root["data-figure-right"]) <= viewport, "a figure runs past the window's edge"
    assert int(root["data-row-scroll-width"]) <= int(root["data-row-client-width"]), "the figure row overflows"


def test_the_report_page_keeps_figures_within_its_width():
    """The stylesheet scales images to the page (no browser needed: the rule the browser test measures)."""
    html = render_html("![rgp.png](rgp.png)")
    style = re.search(r"<style>(.*?)</style>", html).group(1)
    assert re.search(r"img\{[^}]*max-width:100%", style) and "height:auto" in style
