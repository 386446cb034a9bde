"""The runner (records, resume, failures, determinism under offline) and the report (numbers equal
hand-computed metrics), end to end on a small real bank and a hand-written task set."""

from __future__ import annotations

import json
from statistics import mean

import polars as pl
from click.testing import CliRunner

from memora_graph.bench.aggregate import planning_panel
from memora_graph.bench.report import build_report, write_report
from memora_graph.bench.run import load_run, run_bench
from memora_graph.cli import main
from memora_graph.stats import bank_stats

CONDS = "no_memory,flat_1d_raw,flat_1d_edited,graph_2d_raw,graph_2d_edited"


def _run(bank, raw, tasks, out, conds=CONDS, workers=1):
    return run_bench(bank, out, conditions=conds, participants=["P37"], tasks=tasks, raw_bank=raw, workers=workers)


def test_run_records_resume_and_determinism(small_bank, small_raw_bank, tiny_tasks, tmp_path):
    bank, _ = small_bank
    first = _run(bank, small_raw_bank, tiny_tasks, tmp_path / "a")
    assert first.done == 5 * 4 and first.failed == 0
    run = load_run(tmp_path / "a")
    for rec in run["eam_qa"]["flat_1d_edited"]:
        assert rec["predicted"] in "ABCDE" and 1 <= rec["n_tool_calls"] <= 12
        assert set(rec["time"]) == {"model_s", "tools_s", "other_s", "total_s"}
        assert all(c["result_chars"] > 0 for c in rec["tool_calls"])
    plan = next(r for r in run["planning"]["graph_2d_edited"] if r["split"] == "replay")
    assert plan["plan_text"].startswith("1. ") and plan["generated_plan"]
    assert {"action", "entity", "location"} <= set(plan["structured_steps"][0])
    assert run["planning"]["no_memory"][0]["n_tool_calls"] == 0
    manifest = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert manifest["backend"] == "offline" and manifest["task_set_hash"] and manifest["code_version"]
    assert pl.read_parquet(tmp_path / "a" / "results.parquet").height == 20

    again = _run(bank, small_raw_bank, tiny_tasks, tmp_path / "a")
    assert again.done == 0 and again.skipped == 20
    # a record lost from the file (a killed run) is run again, and only that one
    path = tmp_path / "a" / "records" / "eam_qa" / "graph_2d_raw.jsonl"
    path.write_text(path.read_text().splitlines()[0] + "\n")
    assert _run(bank, small_raw_bank, tiny_tasks, tmp_path / "a").done == 1

    # two worker processes give exactly the records of one process
    other = _run(bank, small_raw_bank, tiny_tasks, tmp_path / "b", workers=2)
    assert other.done == 20 and json.loads((tmp_path / "b" / "manifest.json").read_text())["workers"] == 2
    strip = lambda recs: [(r["item_id"], r.get("predicted"), r.get("plan_text"), r.get("final_text"),  # noqa: E731
                           [(c["name"], c["arguments"]) for c in r["tool_calls"]]) for r in recs]
    for kind in ("eam_qa", "planning"):
        for c, recs in load_run(tmp_path / "b")[kind].items():
            assert strip(sorted(recs, key=lambda r: r["item_id"])) == strip(
                sorted(load_run(tmp_path / "a")[kind][c], key=lambda r: r["item_id"]))


def test_a_failing_item_is_recorded_and_the_run_goes_on(small_bank, tiny_tasks, tmp_path):
    bank, _ = small_bank
    empty = tmp_path / "not-a-bank"
    empty.mkdir()
    summary = run_bench(bank, tmp_path / "r", conditions="memora_episodic,no_memory", participants=["P37"],
                        tasks=tiny_tasks, kinds=("eam_qa",), episodic_bank=empty)
    recs = load_run(tmp_path / "r")["eam_qa"]
    assert len(recs["no_memory"]) == 2 and all(r["status"] == "ok" for r in recs["no_memory"])
    assert summary.failed == 2
    assert all(r["status"] == "failed" and r["predicted"] == "" and "no memory bank" in r["error"]
               for r in recs["memora_episodic"])
    assert build_report(tmp_path / "r")["eam_qa"]["conditions"]["memora_episodic"]["n_failed_items"] == 2


def test_report_numbers_equal_hand_computed_metrics(small_bank, small_raw_bank, tiny_tasks, tmp_path):
    bank, _ = small_bank
    _run(bank, small_raw_bank, tiny_tasks, tmp_path / "r", conds=CONDS + ",memora_full")
    run = load_run(tmp_path / "r")
    rep = build_report(tmp_path / "r")
    for c, recs in run["eam_qa"].items():
        s = rep["eam_qa"]["conditions"][c]
        assert s["accuracy"] == mean(r["predicted"] == r["correct_answer"] for r in recs)
        assert s["e_rate"] == mean(r["predicted"] == "E" for r in recs)
    for c, recs in run["planning"].items():
        for split in ("replay", "generalize"):
            scores = [r["scores"] for r in recs if r["split"] == split]
            oe = [s["order_exec"] for s in scores if s["order_exec"] is not None]
            assert rep["planning"][c][split]["order_exec"] == (round(mean(oe), 4) if oe else None)
            assert rep["planning"][c][split] == planning_panel(scores)
    paths = write_report(tmp_path / "r")
    md = paths["markdown"].read_text()
    assert "not an LLM" in md and "Flat-1D (raw)" in md and "OrderExec" in md
    assert "<table>" in paths["html"].read_text() and json.loads(paths["json"].read_text())["planning"]
    # figures: real PNGs, linked from the markdown and the HTML
    for name in ("rgp", "compression", "decisions"):
        assert paths[name].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"({name}.png)" in md
    page = paths["html"].read_text()
    assert '<img src="rgp.png"' in page
    # the page renders the markdown: no literal ** or backticks, emphasis as HTML
    assert "**" not in page and "`" not in page and "<strong>not an LLM</strong>" in page
    # names: each condition's label beside the name runs use, and every column explained in the report itself
    assert "| Flat-1D (raw) | `flat_1d_raw` |" in md and "<code>flat_1d_raw</code>" in page
    assert "## Reading this report" in md
    for column in ("E-rate %", "`memora_committed`", "`parametric_missed_memora_committed`", "RGP", "OrderExec"):
        assert f"| {column} |" in md, column
    # tool calls per store add up to the calls in the records, each tool in its store
    for c, recs in {**run["eam_qa"], **{k: run["eam_qa"].get(k, []) + v for k, v in run["planning"].items()}}.items():
        calls = [t["name"] for r in recs for t in r["tool_calls"]]
        per = rep["tool_calls_per_store"].get(c, {"total": 0, "calls": {}})
        assert per["total"] == len(calls)
        if c == "memora_full":
            assert per["calls"].get("Inferred", 0) == sum(n in ("get_routine_skill", "get_preferences") for n in calls)
            assert per["calls"].get("Entity", 0) == sum(n in ("search_objects", "get_object_history") for n in calls)
    # memory formation: the bank's compression and decision counts
    form = rep["memory_formation"]
    stats = bank_stats(bank, ["P37"]).to_dicts()[0]
    assert form["decisions"] == stats_decisions(bank) and sum(form["decisions"].values()) == stats["decisions"]
    curve = form["participants"]["P37"]
    assert curve["without_editor"][-1] == stats["state_events"] and curve["with_editor"][-1] == stats["entities"]
    assert curve["without_editor"] == sorted(curve["without_editor"])  # cumulative


def stats_decisions(bank) -> dict[str, int]:
    from memora_graph.bank import Bank

    with Bank(bank).open("P37") as store:
        return {r["op"]: int(r["n"]) for r in store.rows("decision_mix", participant="P37")}


def _write(run, kind, cond, recs):
    path = run / "records" / kind / f"{cond}.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in recs))


def test_report_views_and_lift_on_hand_made_records(tmp_path):
    """Four questions for one participant; predictions chosen so every view is easy to count."""
    truth = {"q1": ("SPref", "A"), "q2": ("SPref", "B"), "q3": ("SRoutine", "C"), "q4": ("ERecall", "E")}
    preds = {
        "no_memory": {"q1": "A", "q2": "A", "q3": "A", "q4": "A"},        # right on q1 only
        "flat_1d_edited": {"q1": "A", "q2": "E", "q3": "C", "q4": "E"},
        "memora_episodic": {"q1": "A", "q2": "A", "q3": "E", "q4": "E"},
        "memora_full": {"q1": "A", "q2": "B", "q3": "C", "q4": "D"},      # commits on all four
    }
    for c, p in preds.items():
        _write(tmp_path, "eam_qa", c, [{"item_id": q, "question_id": q, "qa_type": t, "correct_answer": a,
                                       "predicted": p[q], "participant": "P01", "status": "ok", "tool_calls": [],
                                       "time": {"total_s": 1.0}} for q, (t, a) in truth.items()])
    rep = build_report(tmp_path)
    views = rep["eam_qa"]["views"]
    assert views["full"]["conditions"]["memora_full"]["pooled"] == 3 / 4
    # committed = all four; parametric missed q2, q3, q4 -> headline ids {q2, q3, q4}
    head = views["parametric_missed_memora_committed"]["conditions"]
    assert head["memora_full"]["n"] == 3 and head["memora_full"]["pooled"] == 2 / 3
    assert head["flat_1d_edited"]["pooled"] == 2 / 3 and head["memora_episodic"]["pooled"] == 1 / 3
    lift = rep["eam_qa"]["consolidation_lift_pp"]["parametric_missed_memora_committed"]
    assert lift == {"SPref": 100.0, "SHabit": None, "SRoutine": 100.0, "ERecall": -100.0}
    vs = rep["eam_qa"]["memora_vs_best_baseline"]["full"]
    assert vs["SPref"]["delta_pp"] == 50.0 and vs["SPref"]["best_baseline"] == "flat_1d_edited"
    assert views["commit_rate"] == 1.0


def test_cli_run_and_report(small_bank, tiny_tasks, tmp_path):
    bank, _ = small_bank
    out = tmp_path / "cli"
    runner = CliRunner()
    res = runner.invoke(main, ["bench", "run", str(bank), "--out", str(out), "--tasks", str(tiny_tasks),
                               "--participants", "P37", "--conditions", "no_memory,graph_2d_edited", "--quiet"])
    assert res.exit_code == 0, res.output
    assert "8 items run (0 failed)" in res.output
    res = runner.invoke(main, ["bench", "report", str(out)])
    assert res.exit_code == 0 and "Graph-2D (processed)" in res.output and (out / "report.html").exists()
    res = runner.invoke(main, ["bench", "run", str(bank), "--out", str(tmp_path / "x"), "--tasks", str(tiny_tasks),
                               "--participants", "P37", "--conditions", "flat_1d_raw", "--quiet"])
    assert res.exit_code == 1 and "--raw-bank" in res.output


def test_the_compression_figure_says_where_its_curve_stops():
    """The curve shows the first CURVE_SEGMENTS segments: a longer memory's axis and title say so, and give
    the compression at the cut beside the whole memory's (the title once claimed 35.3x over a curve cut at ~14x)."""
    from memora_graph.bench.report import CURVE_SEGMENTS, compression_words

    long = {"participants": {"P01": {"without_editor": list(range(1, 400))}}, "median_compression": 35.3}
    words = compression_words(long, without_at_cut=140.0, edited_at_cut=10.0)
    assert f"the first {CURVE_SEGMENTS} of up to 399 segments" in words["xlabel"]
    assert words["title"] == (f"Cumulative records, 1 participant: 14.0x at segment {CURVE_SEGMENTS}, "
                              "35.3x over the whole memory (median)")
    short = {"participants": {p: {"without_editor": [1, 2, 3]} for p in ("P01", "P02")}, "median_compression": 2.0}
    words = compression_words(short, 3.0, 1.5)
    assert words["xlabel"].startswith("segments") and words["title"].endswith("2 participants; median compression 2.0x")
