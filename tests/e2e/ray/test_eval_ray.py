"""`memora bench run --executor ray` on a local Ray instance with 2 CPUs (`pytest -m ray`): one task per
(condition, participant) shard gives the records of a local run, apart from timings; a re-run
resumes; a shard that fails on every attempt is reported after the others are merged."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from memora_graph.bench.run import load_run, run_bench
from memora_graph.cli import main
from memora_graph.executors import Executor, TasksFailed

pytestmark = pytest.mark.ray

CONDS = "no_memory,flat_1d_edited,graph_2d_edited,memora_full"


@pytest.fixture(scope="module")
def two_participant_tasks(tmp_path_factory):
    """A generated task set for P09 and P37 (the participants of `small_bank`)."""
    from memora_graph.bench.generate import generate_suite, write_generated
    from memora_graph.perceive.annotations import load_annotations

    suite, report = generate_suite(load_annotations(participants=["P09", "P37"]), seed=1, embedder=None)
    root = tmp_path_factory.mktemp("tasks") / "release"
    write_generated(suite, report, root)
    return root


def _untimed(rec: dict) -> dict:
    """A record without its timings: `time`, and each tool call's `seconds`."""
    out = {k: v for k, v in rec.items() if k != "time"}
    out["tool_calls"] = [{k: v for k, v in c.items() if k != "seconds"} for c in rec.get("tool_calls", [])]
    return out


def _records(out) -> dict:
    """Every record by (kind, condition, item), without its timings."""
    got = {}
    for kind, per in load_run(out).items():
        for cond, recs in per.items():
            for r in recs:
                got[(kind, cond, r["item_id"])] = _untimed(r)
    return got


def _run(bank, tasks, out, **kw):
    return run_bench(bank, out, conditions=CONDS, participants=["P09", "P37"], tasks=tasks, limit=2, **kw)


def test_a_ray_evaluation_writes_the_local_records(ray_local, small_bank, two_participant_tasks, tmp_path):
    bank, _ = small_bank
    local = _run(bank, two_participant_tasks, tmp_path / "local", workers=1)
    seen = []
    on_ray = _run(bank, two_participant_tasks, tmp_path / "ray", executor=Executor("ray"), on_item=seen.append)
    assert on_ray.done == local.done > 0 and on_ray.failed == local.failed
    assert len(seen) == on_ray.done and len({(r["condition"], r["item_id"]) for r in seen}) == on_ray.done
    want, got = _records(tmp_path / "local"), _records(tmp_path / "ray")
    assert {p for _, _, p in want} and got.keys() == want.keys()
    assert {r["participant"] for r in got.values()} == {"P09", "P37"}
    assert got == want
    for rec in load_run(tmp_path / "ray")["eam_qa"]["memora_full"]:
        assert set(rec["time"]) == {"model_s", "tools_s", "other_s", "total_s"}
    assert (tmp_path / "ray" / "results.parquet").exists()
    # resumed: nothing is run again
    again = _run(bank, two_participant_tasks, tmp_path / "ray", executor=Executor("ray"))
    assert again.done == 0 and again.skipped == local.done


def test_a_failing_shard_is_retried_then_reported(ray_local, small_bank, two_participant_tasks, tmp_path):
    bank, _ = small_bank
    ex = Executor("ray", retries=1, fail_attempts={"no_memory/P09": 99, "memora_full/P37": 1})
    with pytest.raises(TasksFailed) as err:
        _run(bank, two_participant_tasks, tmp_path / "r", executor=ex)
    assert err.value.failed.keys() == {"no_memory/P09"} and "failed on all 2 attempt(s)" in str(err.value)
    got = _records(tmp_path / "r")
    assert not [k for k in got if k[1] == "no_memory" and got[k]["participant"] == "P09"]
    assert [k for k in got if k[1] == "memora_full" and got[k]["participant"] == "P37"]  # retried, merged
    # the same command again runs only the failed shard's items
    again = _run(bank, two_participant_tasks, tmp_path / "r", executor=Executor("ray"))
    assert again.done > 0 and again.skipped == len(got)
    assert len(_records(tmp_path / "r")) == len(got) + again.done


def test_the_command_takes_the_executor(ray_local, small_bank, two_participant_tasks, tmp_path):
    bank, _ = small_bank
    r = CliRunner().invoke(main, ["bench", "run", str(bank), "--out", str(tmp_path / "c"), "--conditions", "no_memory",
                                  "--participants", "P09,P37", "--tasks", str(two_participant_tasks), "--limit", "1",
                                  "--executor", "ray", "--quiet"])
    assert r.exit_code == 0, r.output
    assert "items run (0 failed)" in r.output
    assert json.loads((tmp_path / "c" / "manifest.json").read_text())["participants"] == ["P09", "P37"]
