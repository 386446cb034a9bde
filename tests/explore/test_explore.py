"""`memora explore`: the page's data against the bank, and the page itself in a real headless Chromium."""

from __future__ import annotations

import json
import re

import pytest
from click.testing import CliRunner
from support.browser import CHROMIUM, NO_CHROMIUM, dump_dom, elements, screenshot

from memora_graph.cli import main
from memora_graph.explore import embed_json, explorer_data, render_page, write_explorer
from memora_graph.stats import bank_stats

COUNTS = ("videos", "segments", "entities", "state_events", "places", "routines", "preferences")


def needs_chromium(test):
    """A page test in a real browser: marked `browser`, skipped (saying why) without Chromium."""
    return pytest.mark.browser(pytest.mark.skipif(CHROMIUM is None, reason=NO_CHROMIUM)(test))


@pytest.fixture(scope="module")
def p37(small_bank):
    path, _ = small_bank
    stats = bank_stats(path, ["P37"]).to_dicts()[0]
    return path, explorer_data(path, "P37"), stats


def _page(tmp_path, data, name="page.html"):
    out = tmp_path / name
    out.write_text(render_page(data), encoding="utf-8")
    return out


def test_data_holds_the_whole_memory(p37):
    _, data, stats = p37
    assert len(data["videos"]) == stats["videos"]
    assert len(data["segments"]) == stats["segments"]
    assert len(data["events"]) == stats["state_events"]
    assert len(data["entities"]) == stats["entity_records"]
    assert sum(e["status"] == "active" for e in data["entities"]) == stats["entities"]
    assert len(data["places"]) == stats["places"]
    assert (len(data["routines"]), len(data["preferences"])) == (stats["routines"], stats["preferences"])
    segment_ids = {s["id"] for s in data["segments"]}
    assert all(e["segment"] in segment_ids for e in data["events"])  # every state is placed on the timeline
    supported = [r for r in data["routines"] + data["preferences"] if r["segments"]]
    assert supported and all(set(r["segments"]) <= segment_ids for r in supported)
    assert any(r["entities"] for r in data["routines"])


def test_page_is_one_file_that_fetches_nothing(p37, tmp_path):
    path, _, _ = p37
    out, _ = write_explorer(path, "P37", tmp_path / "memory.html")
    html = out.read_text(encoding="utf-8")
    assert "default-src 'none'" in html  # the browser refuses any fetch (and reports it, see below)
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)|@import|url\(\s*["']?https?:""", html, re.I)
    assert [p.name for p in tmp_path.iterdir()] == ["memory.html"]


def test_embedded_json_cannot_close_its_script_element():
    data = {"participant": "P99", "summary": "</script><script>alert(1)</script><!-- x"}
    text = embed_json(data)
    assert "<" not in text and json.loads(text) == data


def test_cli_writes_the_page_and_has_examples(p37, tmp_path):
    path, _, _ = p37
    out = tmp_path / "m.html"
    res = CliRunner().invoke(main, ["explore", str(path), "--participant", "P37", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert out.is_file() and "278 segments" in res.output
    help_ = CliRunner().invoke(main, ["explore", "--help"])
    assert "Examples:" in help_.output and "memora explore banks/epic --participant P01" in help_.output
    missing = CliRunner().invoke(main, ["explore", str(path), "--participant", "P02", "--out", str(out)])
    assert missing.exit_code == 1 and "Error:" in missing.output and "P02" in missing.output


# -- in a real browser -------------------------------------------------------------------------------


def _root(dom: str) -> dict:
    return elements(dom, "html")[0]


@needs_chromium
def test_page_renders_counts_and_views_without_errors(p37, tmp_path):
    _, data, stats = p37
    dom = dump_dom(_page(tmp_path, data))
    root = _root(dom)
    assert root["data-errors"] == "", root["data-errors"]
    assert int(root["data-rendered"]) >= 1  # the script ran to the end
    shown = {a["data-count"]: int(a["data-value"]) for a in elements(dom, "div", **{"class": "count"})}
    assert {k: shown[k] for k in COUNTS} == {k: stats[k] for k in COUNTS}
    assert re.search(r">\s*278\s*<", dom)  # and as text, not only in attributes
    timeline = [a for a in elements(dom, "rect") if "seg" in a.get("class", "").split()]
    assert len(timeline) == stats["segments"] and {a["data-segment"] for a in timeline} == {s["id"] for s in data["segments"]}
    assert all(a["data-hit"] == "1" for a in timeline)  # no filter: everything is lit
    assert len(elements(dom, "div", **{"class": "card"})) == stats["routines"] + stats["preferences"]
    assert elements(dom, "path", **{"class": "mark"})  # the editor's decisions on the swimlanes
    kinds = {a.get("data-kind") for a in elements(dom, "g") if "gnode" in a.get("class", "")}
    assert {"object", "place"} <= kinds and kinds & {"routine", "preference"}


@needs_chromium
def test_filters_by_object_and_place_update_every_view(p37, tmp_path):
    _, data, _ = p37
    page = _page(tmp_path, data)
    obj = next(e for e in data["entities"] if e["status"] == "active")  # the most observed object
    ids = {obj["id"]} | {e["id"] for e in data["entities"] if e["merged_into"] == obj["id"]}
    with_obj = {e["segment"] for e in data["events"] if e["entity"] in ids}
    dom = dump_dom(page, fragment=f"object={obj['id']}")
    assert _root(dom)["data-errors"] == ""
    lit = {a["data-segment"] for a in elements(dom, "rect", data_hit="1")}
    assert lit == with_obj and 0 < len(lit) < len(data["segments"])
    lanes = {a["data-entity"] for a in elements(dom, "text") if "lane-label" in a.get("class", "")}
    assert lanes and lanes <= ids
    cards = {a["data-id"] for a in elements(dom, "div", **{"class": "card"})}
    expected = {r["id"] for r in data["routines"] + data["preferences"]
                if set(r["entities"]) & ids or obj["object_id"] in (r.get("key_objects") or r.get("objects") or [])}
    assert cards == expected and len(cards) < len(data["routines"]) + len(data["preferences"])

    place = data["places"][1]["id"]
    dom = dump_dom(page, fragment=f"object={obj['id']}&place={place}")
    lit = {a["data-segment"] for a in elements(dom, "rect", data_hit="1")}
    assert lit == {s["id"] for s in data["segments"] if s["place"] == place} & with_obj
    dom = dump_dom(page, fragment=f"place={place}")
    lit = {a["data-segment"] for a in elements(dom, "rect", data_hit="1")}
    assert lit == {s["id"] for s in data["segments"] if s["place"] == place}
    assert [a["class"] for a in elements(dom, "span", data_place=place)] == ["key on"]  # the legend shows the filter


@needs_chromium
def test_hostile_text_is_shown_as_text(p37, tmp_path):
    _, data, _ = p37
    data = json.loads(json.dumps(data))
    hostile = '</script><script>document.documentElement.setAttribute("data-pwned","1")</script><img src=x onerror=alert(1)>'
    data["segments"][0]["summary"] = hostile
    sid = data["segments"][0]["id"]
    dom = dump_dom(_page(tmp_path, data), fragment=f"segment={sid}")
    root = _root(dom)
    assert root["data-errors"] == "" and "data-pwned" not in root
    assert not elements(dom, "img")
    assert "&lt;/script&gt;&lt;script&gt;" in dom  # the segment panel shows the text as written


@needs_chromium
def test_screenshot_shows_the_page(p37, tmp_path):
    from PIL import Image

    _, data, _ = p37
    png = screenshot(_page(tmp_path, data), tmp_path / "shot.png", size=(1400, 1000))
    with Image.open(png) as im:
        assert im.size == (1400, 1000)
        colours = im.convert("RGB").resize((140, 100)).getcolors(maxcolors=100_000)
    assert len(colours) > 50  # a rendered page, not a blank one


@needs_chromium
def test_a_memory_without_routines_renders(p37, tmp_path):
    _, data, stats = p37
    data = {**data, "routines": [], "preferences": []}  # a MEMORA-Episodic build has none
    dom = dump_dom(_page(tmp_path, data))
    assert _root(dom)["data-errors"] == ""
    shown = {a["data-count"]: int(a["data-value"]) for a in elements(dom, "div", **{"class": "count"})}
    assert (shown["routines"], shown["preferences"], shown["segments"]) == (0, 0, stats["segments"])
    assert "not consolidated" in dom and not elements(dom, "div", **{"class": "card"})


def test_tasks_are_on_the_timeline_data_with_their_goals_and_stages(p37):
    _, data, _ = p37
    tasks = data["tasks"]
    assert tasks, "a consolidated bank has tasks"
    videos = {v["id"] for v in data["videos"]}
    segments = {s["id"] for s in data["segments"]}
    for t in tasks:
        assert t["video"] in videos and t["goal"] and t["t_start"] <= t["t_end"]
        assert set(t["segments"]) <= segments and set(t["stages"]) == {"setup", "main", "finish", "cleanup"}
    assert [(t["video"], t["t_start"]) for t in tasks] == sorted((t["video"], t["t_start"]) for t in tasks)
