"""`memora bench compare`: two real runs of the same code compare identical (timings aside); an
edited answer, an edited tool argument and a missing record are each found and counted, and
`--check` turns a difference into exit status 1."""

from __future__ import annotations

import json
import shutil

from click.testing import CliRunner

from memora_graph.bench.compare import compare_runs, without_timings
from memora_graph.bench.run import run_bench
from memora_graph.cli import main


def _rewrite(path, edit):
    recs = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    recs = edit(recs)
    path.write_text("".join(json.dumps(r) + "\n" for r in recs))


def test_compare_two_runs(small_bank, tiny_tasks, tmp_path):
    bank, _ = small_bank
    for name in ("a", "b"):
        run_bench(bank, tmp_path / name, conditions="no_memory,memora_full", participants=["P37"], tasks=tiny_tasks,
                  workers=1)
    a, b = tmp_path / "a", tmp_path / "b"
    # the runs took different times, and the comparison does not see it
    recs = [json.loads(x) for x in (a / "records" / "eam_qa" / "memora_full.jsonl").read_text().splitlines()]
    assert recs and all("time" in r for r in recs) and all("time" not in without_timings(r) for r in recs)
    same = compare_runs(a, b)
    assert same.identical and not same.differences
    assert {(r["kind"], r["condition"]) for r in same.rows} == {
        (k, c) for k in ("eam_qa", "planning") for c in ("no_memory", "memora_full")}
    qa = next(r for r in same.rows if r["kind"] == "eam_qa" and r["condition"] == "memora_full")
    assert qa["records_a"] == qa["records_b"] == 2 and qa["accuracy_a"] == qa["accuracy_b"]
    res = CliRunner().invoke(main, ["bench", "compare", str(a), str(b), "--check"])
    assert res.exit_code == 0 and "identical (timings aside)" in res.output

    # b: one answer changed, one tool argument changed, one planning record lost
    c = tmp_path / "c"
    shutil.copytree(b, c)
    first_id = recs[0]["item_id"]

    def flip(rs):
        gold = rs[0]["correct_answer"]  # right becomes wrong, wrong becomes right: accuracy moves
        rs[0]["predicted"] = gold if rs[0]["predicted"] != gold else ("A" if gold != "A" else "B")
        rs[0]["is_correct"] = not rs[0]["is_correct"]
        rs[1]["tool_calls"][0]["arguments"] = {"query": "something else"}
        return rs

    _rewrite(c / "records" / "eam_qa" / "memora_full.jsonl", flip)
    _rewrite(c / "records" / "planning" / "no_memory.jsonl", lambda rs: rs[1:])
    diff = compare_runs(a, c)
    assert not diff.identical
    qa = next(r for r in diff.rows if r["kind"] == "eam_qa" and r["condition"] == "memora_full")
    assert qa["differ"] == 2 and qa["answers_changed"] == 1 and qa["accuracy_a"] != qa["accuracy_b"]
    assert "predicted (1)" in qa["fields_differing"] and "tool_calls (1)" in qa["fields_differing"]
    plan = next(r for r in diff.rows if r["kind"] == "planning" and r["condition"] == "no_memory")
    assert plan["only_a"] == 1 and plan["only_b"] == 0 and plan["differ"] == 0
    assert any(d.item_id == first_id and "predicted" in d.fields for d in diff.differences)

    res = CliRunner().invoke(main, ["bench", "compare", str(a), str(c), "--check"])
    assert res.exit_code == 1 and f"differs: eam_qa memora_full {first_id}" in res.output
    res = CliRunner().invoke(main, ["bench", "compare", str(a), str(c), "--json", "--show", "0"])
    assert res.exit_code == 0 and {r["condition"] for r in json.loads(res.output)} == {"no_memory", "memora_full"}
    res = CliRunner().invoke(main, ["bench", "compare", str(a), str(tmp_path)])
    assert res.exit_code == 1 and f"{tmp_path}: not a run directory" in res.output and "Traceback" not in res.output


def test_the_readers_vector_cache_changes_speed_not_records(small_bank, tiny_tasks, tmp_path, monkeypatch):
    """The offline reader's text vectors (memora_graph/vector_store.py) kept on disk: a run with
    them in memory only, a run that fills the file, and a later run that reads every vector
    from it give the same records."""
    from memora_graph import vector_store
    from memora_graph.embed import get_embedder
    from memora_graph.vector_store import TextVectors

    bank, _ = small_bank
    encoder = get_embedder().inner.query
    runs = {}
    for name, tv in (("memory", TextVectors(encoder, persist=False)), ("cold", TextVectors(encoder, root=tmp_path)),
                     ("warm", TextVectors(encoder, root=tmp_path))):
        monkeypatch.setattr(vector_store, "_QUERY", {(id(encoder), "query"): tv})
        res = run_bench(bank, tmp_path / name, conditions="no_memory,flat_1d_edited,memora_full", participants=["P37"],
                        tasks=tiny_tasks, workers=1)
        assert res.failed == 0
        runs[name] = tv
    assert runs["memory"].encoded > 10 and runs["memory"].path is None
    assert runs["cold"].encoded == runs["memory"].encoded and runs["cold"].from_disk == 0
    assert runs["warm"].encoded == 0 and runs["warm"].from_disk == runs["cold"].encoded
    for other in ("cold", "warm"):
        assert compare_runs(tmp_path / "memory", tmp_path / other).identical
