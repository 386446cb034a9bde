"""The ReAct loop against a real OpenAI-compatible HTTP server on 127.0.0.1 (scripted model turns):
tool-call formats, budgets, the forced final answer, repeated calls, the 3-call cap, scoping."""

from __future__ import annotations

import json

import pytest
from support.scripted_server import ScriptedServer, Turn, tool_call

from memora_graph.agent.loop import ModelPolicy, run_agent
from memora_graph.agent.prompts import PREMATURE_RETRY
from memora_graph.baselines.flat1d import FlatHit, FlatSearchResult
from memora_graph.bench.run import make_policy
from memora_graph.llm import get_backend
from memora_graph.retrieve import tool_set

QUESTION = {"question_id": "q1", "participant_id": "P09", "qa_type": "SPref", "question": "What does P09 use?",
            "choices": ["a knife", "a fork", "a spoon", "a pan", "The information is not available based on the given context"],
            "video_id": "P09_101", "video_ids": ["P09_101"], "video_scope": ["P09_101"]}
TASK = {"task_id": "t1", "participant_id": "P09", "task_query": "Help P09 wash the plate."}


class RecordingMemory:
    """A memory whose `search` records each call; used to count real executions."""

    def __init__(self):
        self.calls = []

    def search(self, query, top_k=10):
        self.calls.append(query)
        return FlatSearchResult(query=query, results=[FlatHit(kind="activity", text=f"record about {query}",
                                                              video="P09_101", time=0.0, similarity=0.5)])


def _tools(participant="P09"):
    memory = RecordingMemory()
    return tool_set("flat1d", ["search"], participant, memory), memory


def _policy(server, **options):
    return ModelPolicy(get_backend("openai", base_url=server.base_url, model="m", **options))


def test_native_tool_calls_then_answer():
    toolset, memory = _tools()
    with ScriptedServer([Turn(tool_calls=[tool_call("search", {"query": "knife"})]), "I checked.\nAnswer: A"]) as server:
        res = run_agent(_policy(server), toolset, "eam_qa", QUESTION, "flat1d")
        second = server.requests[1]["messages"]
    assert memory.calls == ["knife"]
    assert res.final_text.endswith("Answer: A") and res.iterations == 2 and not res.forced
    assert second[-2]["tool_calls"][0]["function"]["name"] == "search"
    assert second[-1]["role"] == "tool" and "record about knife" in second[-1]["content"]
    assert res.tool_calls[0]["format"] == "native" and res.tool_calls[0]["result_chars"] > 0


def test_qwen_and_hermes_text_tool_calls():
    toolset, memory = _tools()
    script = ['<tool_call>{"name": "search", "arguments": {"query": "plate"}}</tool_call>',
              "<function=search><parameter=query>sponge</parameter></function>",
              "Answer: C"]
    with ScriptedServer(script) as server:
        res = run_agent(_policy(server), toolset, "eam_qa", QUESTION, "flat1d")
        last = server.requests[2]["messages"][-1]
    assert memory.calls == ["plate", "sponge"]
    assert last["role"] == "user" and "<tool_response>" in last["content"] and "sponge" in last["content"]
    assert [c["format"] for c in res.tool_calls] == ["text", "text"] and res.final_text == "Answer: C"


@pytest.mark.parametrize("kind,view,budget", [("eam_qa", QUESTION, 5), ("planning", TASK, 8)])
def test_budget_and_forced_final_answer_without_tools(kind, view, budget):
    toolset, memory = _tools()
    final = "Answer: B" if kind == "eam_qa" else "Plan:\n1. Wash the plate at the sink\n2. Place the plate on the rack"
    script = [Turn(tool_calls=[tool_call("search", {"query": f"q{i}"})]) for i in range(budget - 1)] + [final]
    with ScriptedServer(script) as server:
        res = run_agent(_policy(server), toolset, kind, view, "flat1d")
        requests = server.requests
    assert len(requests) == budget and res.iterations == budget and res.forced
    assert len(memory.calls) == budget - 1
    assert all("tools" in r for r in requests[:-1]) and "tools" not in requests[-1]
    forced_prompt = requests[-1]["messages"][-1]["content"]
    assert "disabled" in forced_prompt and "search(" in forced_prompt
    assert res.final_text == final


def test_forced_turn_ignores_tool_calls():
    toolset, memory = _tools()
    script = [Turn(tool_calls=[tool_call("search", {"query": f"q{i}"})]) for i in range(5)]
    with ScriptedServer(script) as server:
        res = run_agent(_policy(server), toolset, "eam_qa", QUESTION, "flat1d")
    assert len(memory.calls) == 4 and res.iterations == 5 and res.final_text == ""


def test_repeated_identical_call_is_answered_from_the_first_result():
    toolset, memory = _tools()
    script = [Turn(tool_calls=[tool_call("search", {"query": "plate"})]),
              Turn(tool_calls=[tool_call("search", {"query": "plate"}, id="other")]), "Answer: A"]
    with ScriptedServer(script) as server:
        res = run_agent(_policy(server), toolset, "eam_qa", QUESTION, "flat1d")
        shown = server.requests[2]["messages"][-1]["content"]
    assert memory.calls == ["plate"]
    assert [c["duplicate"] for c in res.tool_calls] == [False, True]
    assert json.loads(shown)["_duplicate"] is True


def test_at_most_three_calls_per_response():
    toolset, memory = _tools()
    calls = [tool_call("search", {"query": f"q{i}"}) for i in range(5)]
    with ScriptedServer([Turn(tool_calls=calls), "Answer: A"]) as server:
        res = run_agent(_policy(server), toolset, "eam_qa", QUESTION, "flat1d")
    assert memory.calls == ["q0", "q1", "q2"] and len(res.tool_calls) == 3


def test_premature_reply_gets_one_retry():
    toolset, _ = _tools()
    with ScriptedServer(["hmm", "Answer: D"]) as server:
        res = run_agent(_policy(server), toolset, "eam_qa", QUESTION, "flat1d")
        retry = server.requests[1]["messages"][-1]["content"]
    assert res.retried and res.final_text == "Answer: D" and retry == PREMATURE_RETRY["eam_qa"]


def test_timeout_then_retry_and_default_temperature(tmp_path):
    toolset, _ = _tools()
    with ScriptedServer([Turn(content="Answer: A", delay_s=1.0), "Answer: B"], strict=False) as server:
        policy = make_policy("openai", {"base_url": server.base_url, "model": "m", "timeout_s": 0.3},
                       tmp_path)
        res = run_agent(policy, toolset, "eam_qa", QUESTION, "flat1d")
        temperature = server.requests[-1]["temperature"]
    assert res.final_text == "Answer: B" and temperature == 0.6
    assert policy.backend.call_log.records[0].retries == 1


def test_malformed_tool_json_is_rescued_or_ignored():
    toolset, memory = _tools()
    script = ['<tool_call>{"name": "search", "arguments": {"query": "bowl"</tool_call>', "Answer: E"]
    with ScriptedServer(script) as server:
        res = run_agent(_policy(server), toolset, "eam_qa", QUESTION, "flat1d")
    assert memory.calls == ["bowl"] and res.final_text == "Answer: E"


def test_a_toolset_for_another_participant_is_refused():
    toolset, _ = _tools("P37")
    with pytest.raises(ValueError, match="bound to P37"):
        run_agent(_policy.__class__, toolset, "eam_qa", QUESTION, "flat1d")  # refused before any model call


def test_tool_arguments_cannot_select_another_participant(small_bank):
    from memora_graph.baselines.flat1d import Flat1DMemory

    path, _ = small_bank
    toolset = tool_set("flat1d", ["search"], "P09", Flat1DMemory.load(path, "P09"))
    out = toolset.call("search", {"query": "wash plate", "participant": "P37", "participant_id": "P37"})
    assert out.results and all(r.video.startswith("P09_") for r in out.results)
