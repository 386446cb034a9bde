"""One ToolSpec per tool, and everything derived from it: a tool registered in one place shows up in
the agent schemas, the tool-call parser, the tool sets, `memora tools` / `memora tool` and the
report's per-store table without another file changing. And the contract between consolidation
and the reader: the structured fields consolidation stores are the fields a reader gets."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner
from pydantic import Field

from memora_graph.agent import parse_tool_calls
from memora_graph.agent.offline import evidence_items
from memora_graph.agent.planner import _step, apply_preferences
from memora_graph.bench.report import build_report
from memora_graph.cli import main
from memora_graph.retrieve import (
    MemoryView, Reply, ToolErrorResult, call_tool, first_arguments, get_tool, specs, store_of, tool, tool_schemas,
    tool_set, unregister,
)
from memora_graph.retrieve.args import QueryText, ToolArgs
from memora_graph.retrieve.results import MemoraResult, Record


class CountArgs(ToolArgs):
    noun: QueryText = Field(description="An object noun.")
    limit: int = Field(3, ge=1, description="How many.")


class Count(Record):
    noun: str
    segments: int

    def text(self) -> str:
        return f"{self.noun}: {self.segments} segments"


class CountResult(MemoraResult):
    _lists = ("counts",)
    counts: list[Count]


@pytest.fixture()
def scratch_tool():
    @tool("count_object_uses", args=CountArgs, result=CountResult, store="Scratch store",
          description="How many segments observed an object (a throwaway tool of this test).")
    def count_object_uses(view, noun: str, limit: int = 3) -> Reply:
        n = sum(1 for e in view.entities.values() if noun in e["name"])
        return Reply({"noun": noun}, counts=[Count(noun=noun, segments=n)][:limit])  # the decorator wraps it

    yield count_object_uses
    unregister("count_object_uses")


def test_a_tool_registered_in_one_place_is_everywhere(scratch_tool, small_bank, tmp_path):
    bank, _ = small_bank
    # agent schemas, with the argument model's JSON schema
    schema = next(s for s in tool_schemas() if s["function"]["name"] == "count_object_uses")
    assert schema["function"]["parameters"]["required"] == ["noun"]
    # the tool-call parser: a positional plain-text call fills its first argument
    assert first_arguments()["count_object_uses"] == "noun"
    calls = parse_tool_calls('count_object_uses("knife")')
    assert [(c.name, c.arguments) for c in calls] == [("count_object_uses", {"noun": "knife"})]
    # a tool set of the evaluation: validated, embedded arguments known, errors are observations
    with MemoryView.open(bank, "P37") as view:
        ts = tool_set("memora", ["search", "count_object_uses"], "P37", view)
        assert ts.query_texts([("count_object_uses", {"noun": "knife", "limit": 2})]) == ["knife"]
        out = ts.call("count_object_uses", {"noun": "knife", "who": "P09"})  # unknown keys are dropped
        assert isinstance(out, CountResult) and out.counts[0].segments >= 1
        assert (out.tool, out.participant, out.arguments) == ("count_object_uses", "P37", {"noun": "knife"})
        direct = scratch_tool(view, "knife", limit=1)  # the decorated function itself returns the result
        assert isinstance(direct, CountResult) and direct.model_dump() == out.model_dump()
        assert isinstance(ts.call("count_object_uses", {"limit": 0}), ToolErrorResult)
        assert evidence_items(out)[0]["text"].startswith("knife: ")
    # the commands
    runner = CliRunner()
    listing = runner.invoke(main, ["tools"])
    assert listing.exit_code == 0 and "count_object_uses" in listing.output and "Scratch store" in listing.output
    r = runner.invoke(main, ["tool", str(bank), "count_object_uses", "knife", "--participant", "P37", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["counts"][0]["noun"] == "knife"
    # the report's tool -> store map
    assert store_of("count_object_uses") == "Scratch store"
    rec = {"item_id": "q1", "question_id": "q1", "participant": "P37", "condition": "memora_full", "kind": "eam_qa",
           "qa_type": "SPref", "status": "ok", "predicted": "A", "correct_answer": "A", "is_correct": True,
           "is_unanswerable": False, "n_tool_calls": 2, "tool_calls": [{"name": "count_object_uses"}, {"name": "search"}],
           "time": {"model_s": 0.0, "tools_s": 0.0, "other_s": 0.0, "total_s": 0.0}}
    (tmp_path / "records" / "eam_qa").mkdir(parents=True)
    (tmp_path / "records" / "eam_qa" / "memora_full.jsonl").write_text(json.dumps(rec) + "\n")
    per_store = build_report(tmp_path)["tool_calls_per_store"]["memora_full"]["calls"]
    assert per_store == {"Scratch store": 1, "unified search": 1}


def test_every_spec_validates_its_own_schema_and_names_a_store():
    for spec in specs():
        assert spec.store and spec.description and spec.first_argument in spec.args.model_fields
        assert spec.schema()["function"]["name"] == spec.name
    assert {s.family for s in specs()} == {"memora", "flat1d", "graph2d"}
    assert get_tool("search", "flat1d").store == "Flat-1D records"
    assert get_tool("search_objects").aliases == {"name": "query", "object": "query"}


def test_consolidation_fields_reach_the_reader(small_bank):
    """What the deterministic consolidation stores (storage object and place, habit trigger and next
    action, workflow use and follow-up, routine steps as classes) arrives as typed fields, and the
    reader's plan honours a preference by those fields alone."""
    bank, _ = small_bank
    with MemoryView.open(bank, "P37") as view:
        prefs = call_tool(view, "get_preferences", {"query": "", "top_k": 30}).preferences
        routines = call_tool(view, "get_routine_skill", {"goal_query": "wash", "top_k": 5}).routines
    storage = next(p for p in prefs if p.subtype == "storage" and p.context != "during_use")
    habit = next(p for p in prefs if p.subtype == "habit")
    assert storage.object and storage.preferred_location and storage.context
    assert habit.trigger and habit.next_action and habit.trigger_step.verb and habit.next_step.noun is not None
    assert routines and all(r.steps and len(r.steps) == len(r.canonical_steps) for r in routines)
    assert all(s.verb for r in routines for s in r.steps)
    # the reader reads the fields: a statement it cannot parse changes nothing
    noun = storage.objects[0]
    plan = [_step("take", noun, "counter", grounded=True)]
    reworded = storage.model_copy(update={"preference": "(wording the reader does not parse)"})
    out = apply_preferences(plan, [reworded])
    assert out[-1]["preference"] == storage.preference_id
    assert out[-1]["location"] == storage.preferred_location.lower()
