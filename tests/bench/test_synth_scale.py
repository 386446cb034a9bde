"""Long-horizon memories: `memora bench synth` replays a participant's videos into a growing,
deterministic annotation file; `memora perf scale` builds and measures it end to end; the default
retrieval recipe switches to HNSW from HNSW_MIN_SEGMENTS segments when the indexes exist."""

from __future__ import annotations

import json

import polars as pl
import pytest
from click.testing import CliRunner

from memora_graph.bench.synth import QUALIFIERS, first_video, synthesize
from memora_graph.cli import main
from memora_graph.perceive.annotations import load_annotations


def test_synth_is_deterministic_and_grows(tmp_path):
    a = synthesize("P37", 2.5, tmp_path / "a", seed=3)
    b = synthesize("P37", 2.5, tmp_path / "b", seed=3)
    c = synthesize("P37", 2.5, tmp_path / "c", seed=4)
    assert (tmp_path / "a/annotations.csv").read_bytes() == (tmp_path / "b/annotations.csv").read_bytes()
    assert (tmp_path / "a/annotations.csv").read_bytes() != (tmp_path / "c/annotations.csv").read_bytes()
    source = load_annotations(participants=["P37"])
    df = load_annotations(a.annotations)  # the loader accepts it (times within each video, classes known)
    assert a.replays == 4 and df.height == a.actions > 3 * source.height
    # new video ids, in order, none of the source's
    videos = df["video_id"].unique(maintain_order=True).to_list()
    first = first_video(source["video_id"].unique().to_list())
    assert first == 104 and videos == [f"P37_{first + i}" for i in range(a.videos)]
    assert not set(videos) & set(source["video_id"].to_list())
    # time is monotone in each video, and the hours add up
    raw = pl.read_csv(a.annotations, infer_schema=False)
    for _, g in df.group_by("video_id"):
        starts = g.sort("row")["start_s"].to_list()
        assert starts == sorted(starts)
    info = pl.read_csv(tmp_path / "a/video_info.csv")
    assert info["duration"].sum() == pytest.approx(2.5 * 3600, abs=5)
    assert raw["narration_id"].n_unique() == raw.height
    # renamed objects are in the nouns and the narrations; the first replay is verbatim
    assert a.renamed > 0 and a.new_objects
    nouns = {n for ns in df["all_nouns"].to_list() for n in ns}
    assert set(a.new_objects) <= nouns
    first = df.filter(pl.col("video_id") == videos[0]).head(source.height)
    assert sorted(first["narration"].to_list()) == sorted(source["narration"].to_list())
    renamed = df.filter(pl.col("all_nouns").list.eval(pl.element().str.contains(":(" + "|".join(QUALIFIERS) + ")$"))
                        .list.any())
    assert renamed.height == a.renamed
    said = sum(any(" ".join(reversed(n.split(":")[-2:])) in t for n in ns if n.count(":") >= 2) for t, ns in
               zip(renamed["narration"].to_list(), renamed["all_nouns"].to_list()))  # "small red plate"
    assert said > 0.8 * renamed.height
    assert a.reordered > 0
    # a shorter file is the start of a longer one (the same replays)
    short = synthesize("P37", 1.0, tmp_path / "short", seed=3)
    assert pl.read_csv(short.annotations, infer_schema=False)["narration"].to_list() == \
        raw["narration"].to_list()[: short.actions]


def test_synth_cli_errors(tmp_path):
    r = CliRunner().invoke(main, ["bench", "synth", "--participant", "P99", "--hours", "1", "--out", str(tmp_path)])
    assert r.exit_code == 1 and "no actions of participant P99" in r.output
    r = CliRunner().invoke(main, ["bench", "synth", "--participant", "P37", "--hours", "0", "--out", str(tmp_path)])
    assert r.exit_code == 2


@pytest.fixture(scope="module")
def scaled(tmp_path_factory):
    """`memora perf scale` end to end on one small size of P37 (1 h: its 0.77 h, then part of a
    replay with renamed objects)."""
    work = tmp_path_factory.mktemp("scale")
    r = CliRunner().invoke(
        main, ["perf", "scale", "--participant", "P37", "--sizes", "1", "--work", str(work), "--queries", "2", "--json"])
    assert r.exit_code == 0, r.output + (r.stderr or "")
    return work, json.loads(r.stdout), r.stderr


def test_perf_scale_end_to_end(scaled):
    work, res, log = scaled
    (size,) = res["sizes"]
    assert size["hours"] == 1.0 and size["segments"] > 300 and size["build_s_per_hour"] > 0
    assert size["bank_mb"] > 0 and size["bank_indexed_mb"] > size["bank_mb"]
    assert size["stores_mb"] > 0 and size["stores_rss_mb"] > 50  # measured as a user's bank has them: current
    for recipe in ("inprocess", "hnsw"):
        assert size[f"{recipe}_open_s"] > 0 and size[f"{recipe}_rss_mb"] > 50
        tools = {t["tool"] for t in res["tools"] if t["recipe"] == recipe}
        assert tools == {"search", "search_objects", "get_object_history", "get_state_at_time", "search_activities",
                         "search_patterns", "get_routine_skill", "get_preferences"}
    assert all(t["cold_p95_ms"] >= t["cold_p50_ms"] > 0 for t in res["tools"])
    assert "crossover" in res
    # the memory grew: new video ids and renamed objects are in the graph
    from memora_graph.retrieve.view import MemoryView

    with MemoryView.open(work / "bank-1h", "P37") as view:
        assert view._persisted is not None  # the stores step left them current after the index step
        assert set(view.videos) == {"P37_104", "P37_105"}
        names = {e["name"] for e in view.entities.values()}
    assert any(" ".join(n.split()[:2]).replace(" ", ":") in QUALIFIERS for n in names)  # "red small plate"
    # a second run reuses every finished step (sizes can be run in steps)
    r = CliRunner().invoke(main, ["perf", "scale", "--participant", "P37", "--sizes", "1", "--work",
                                                  str(work), "--json"])
    assert r.exit_code == 0 and json.loads(r.stdout)["sizes"] == res["sizes"]
    assert "build-1h: reusing" in r.stderr and "running" not in r.stderr


def test_default_recipe_switches_to_hnsw_at_the_threshold(scaled, small_bank, monkeypatch):
    from memora_graph.retrieve import view as view_module
    from memora_graph.retrieve.view import MemoryView

    work, res, _ = scaled
    n = res["sizes"][0]["segments"]
    bank = work / "bank-1h"  # has the FTS and HNSW indexes
    monkeypatch.setattr(view_module, "HNSW_MIN_SEGMENTS", n)
    with MemoryView.open(bank, "P37") as view:
        assert view.recipe == "hnsw" and view.config.vector == "hnsw"
    with MemoryView.open(bank, "P37", config="inprocess") as view:  # asked for: kept
        assert view.recipe == "inprocess"
    r = CliRunner().invoke(main, ["tool", str(bank), "search_objects", "knife", "--participant", "P37", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["results"]
    monkeypatch.setattr(view_module, "HNSW_MIN_SEGMENTS", n + 1)
    with MemoryView.open(bank, "P37") as view:
        assert view.recipe == "inprocess"
    monkeypatch.setattr(view_module, "HNSW_MIN_SEGMENTS", 0)
    with MemoryView.open(small_bank[0], "P37") as view:  # no indexes: stays exact, whatever its size
        assert view.recipe == "inprocess"
    monkeypatch.setattr(view_module, "HNSW_MIN_SEGMENTS", None)  # no size measured HNSW faster: never switch
    with MemoryView.open(bank, "P37") as view:
        assert view.recipe == "inprocess"
    from memora_graph.store import index_names

    assert view_module._recipe_by_size({"indexes": list(index_names("fts")) + list(index_names("hnsw")),
                                        "counts": {"segments": 10**9}}) == "inprocess"


def test_crossover_needs_hnsw_faster_in_wall_and_in_cpu():
    from memora_graph.cli.perf.scale import crossover

    def row(h, wall, cpu=(None, None)):
        return {"hours": h, "segments": h * 360, "inprocess_tool_p50_median_ms": wall[0], "hnsw_tool_p50_median_ms": wall[1],
                "inprocess_tool_cpu_p50_median_ms": cpu[0], "hnsw_tool_cpu_p50_median_ms": cpu[1]}

    # 1,000 h as measured: HNSW ahead in wall time (Kùzu's threads on an idle core), behind in CPU
    assert crossover([row(100, (21.3, 27.3), (20.0, 26.0)), row(1000, (101.6, 90.8), (128.8, 134.8))]) is None
    x = crossover([row(10, (5, 9), (5, 9)), row(100, (30, 20), (30, 25)), row(1000, (100, 50), (120, 60))])
    assert x == {"hours": 100, "segments": 36000, "slower_below": {"hours": 10, "segments": 3600}}
    assert crossover([row(100, (30, 20))])["hours"] == 100  # runs saved before CPU was measured: wall alone
