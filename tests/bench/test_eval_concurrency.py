"""`memora bench run --concurrency N` against a real HTTP server on 127.0.0.1 whose model words are
scripted as a function of the request (memora_graph/testing/responders.py): many agent loops in
flight give the records a --concurrency 1 run gives, in the same order; resume and failing items
behave as in a serial run."""

from __future__ import annotations

import json
import shutil

from memora_graph.bench.run import load_run, record_path, run_bench
from memora_graph.testing.responders import agent
from support.scripted_server import ScriptedServer

CONDS = "no_memory,flat_1d_edited,memora_full"


def _tasks_with_a_failing_item(tiny_tasks, tmp_path):
    """The tiny release plus extra questions (one whose reply is not a chat completion)."""
    root = tmp_path / "tasks"
    shutil.copytree(tiny_tasks, root)
    path = root / "eam_qa" / "questions" / "p37.json"
    data = json.loads(path.read_text())
    base = data["questions"][0]
    extra = [{**base, "question_id": f"p37_q01{i:02d}", "question": f"Question {i} about what P37 did with the plate?"}
             for i in range(6)]
    extra.insert(3, {**base, "question_id": "p37_q0199", "question": "FAIL-ITEM: what did P37 do?"})
    data["questions"] += extra
    path.write_text(json.dumps(data))
    return root


def _strip_timings(records):
    out = []
    for r in records:
        r = {k: v for k, v in r.items() if k != "time"}
        r["tool_calls"] = [{k: v for k, v in c.items() if k != "seconds"} for c in r.get("tool_calls") or []]
        out.append(r)
    return out


def _lines(out, kind, cond):
    return [json.loads(line) for line in record_path(out, kind, cond).read_text().splitlines()]


def test_concurrency_gives_the_records_of_a_serial_run(small_bank, tiny_tasks, tmp_path):
    bank, _ = small_bank
    tasks = _tasks_with_a_failing_item(tiny_tasks, tmp_path)
    # 20-60 ms per reply in a random order of completion; at most 8 requests served at once
    with ScriptedServer(responder=agent, latency_s=0.04, jitter=0.5, max_concurrency=8, seed=7) as server:
        def run(out, concurrency):
            return run_bench(bank, out, conditions=CONDS, participants=["P37"], tasks=tasks, backend="openai",
                             backend_options={"base_url": server.base_url, "model": "m", "max_retries": 0},
                             concurrency=concurrency)

        serial = run(tmp_path / "c1", 1)
        before = server.stats()["inflight_max"]
        parallel = run(tmp_path / "c8", 8)
        assert server.stats()["inflight_max"] > before >= 1  # requests really overlapped
    assert before == 1
    assert (serial.done, serial.failed) == (parallel.done, parallel.failed) == (3 * 11, 3)
    for kind in ("eam_qa", "replay", "generalize"):
        for cond in CONDS.split(","):
            a, b = _lines(tmp_path / "c1", kind, cond), _lines(tmp_path / "c8", kind, cond)
            assert _strip_timings(a) == _strip_timings(b), (kind, cond)
    failed = [r for r in _lines(tmp_path / "c8", "eam_qa", "memora_full") if r["status"] == "failed"]
    assert [r["item_id"] for r in failed] == ["p37_q0199"] and "not JSON" in failed[0]["error"]
    calls = [json.loads(line) for line in (tmp_path / "c8" / "model_calls.jsonl").read_text().splitlines()]
    assert len(calls) == len([json.loads(x) for x in (tmp_path / "c1" / "model_calls.jsonl").read_text().splitlines()])
    assert json.loads((tmp_path / "c8" / "manifest.json").read_text())["concurrency"] == 8


def test_concurrent_resume_runs_only_what_is_missing_or_failed(small_bank, tiny_tasks, tmp_path):
    bank, _ = small_bank
    tasks = _tasks_with_a_failing_item(tiny_tasks, tmp_path)
    out = tmp_path / "run"
    with ScriptedServer(responder=agent, latency_s=0.01, jitter=0.5) as server:
        opts = {"base_url": server.base_url, "model": "m", "max_retries": 0}
        first = run_bench(bank, out, conditions="no_memory", participants=["P37"], tasks=tasks, backend="openai",
                          backend_options=opts, concurrency=4, kinds=("eam_qa",))
        served = server.stats()["requests"]
        again = run_bench(bank, out, conditions="no_memory", participants=["P37"], tasks=tasks, backend="openai",
                          backend_options=opts, concurrency=4, kinds=("eam_qa",))
        assert server.stats()["requests"] - served == 1  # only the failed item is asked again
    assert (first.done, first.failed) == (9, 1)
    assert (again.done, again.skipped, again.failed) == (1, 8, 1)
    records = load_run(out)["eam_qa"]["no_memory"]
    assert len(records) == 9


def test_cli_concurrency_option(small_bank, tiny_tasks, tmp_path):
    from click.testing import CliRunner

    from memora_graph.cli import main

    bank, _ = small_bank
    runner = CliRunner()
    with ScriptedServer(responder=agent, latency_s=0.05) as server:
        args = ["bench", "run", str(bank), "--out", str(tmp_path / "run"), "--conditions", "no_memory",
                "--participants", "P37", "--tasks", str(tiny_tasks), "--backend", "openai", "--base-url",
                server.base_url, "--model", "m", "--quiet"]
        bad = runner.invoke(main, [*args, "--concurrency", "0"])
        assert bad.exit_code != 0 and "--concurrency must be at least 1" in bad.output
        assert not (tmp_path / "run").exists()  # refused before anything was written
        ok = runner.invoke(main, [*args, "--concurrency", "4"])
        assert ok.exit_code == 0, ok.output
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["concurrency"] == 4 and "4 items run (0 failed)" in ok.output
