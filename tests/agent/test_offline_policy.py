"""The offline reader: evidence read round-robin across a result's record kinds, preferences honoured
in plans, and a response's several queries embedded in one batch before its calls run."""

from __future__ import annotations

from support.scripted_server import ScriptedServer, Turn, tool_call

from memora_graph.agent.loop import ModelPolicy, run_agent
from memora_graph.agent.offline import OfflinePolicy, read_evidence
from memora_graph.agent.planner import _step, apply_preferences
from memora_graph.baselines.flat1d import FlatHit, FlatSearchResult
from memora_graph.llm import get_backend
from memora_graph.retrieve import MemoryView, tool_set
from memora_graph.retrieve.results import (
    ActivityRecord, ObjectRecord, PatternRecord, PlaceRecord, PreferenceRecord, PreferencesResult, RoutineRecord,
    RoutinesResult, SearchResult,
)

_SCORE = {"vector": 0.5, "fused": 0.01}


def _object(i):
    return ObjectRecord(object_id="pan", entity_id=f"P01:pan{i}", name=f"objects record {i}", kind="pan", category="",
                        visual_properties={}, spatial_info={"location": "", "place": "", "is_fixture": False},
                        state={"current_state": "", "status": "active"}, places=[], used_with=[],
                        time_seen_seconds={"first": {}, "last": {}}, similarity=0.5, score=_SCORE, evidence=[])


def _activity(i):
    return ActivityRecord(segment_id=f"P01_01#t{i:04d}", source_video="P01_01", turn_id=i, time={"start": 0, "end": 10},
                          summary=f"activities record {i}", detailed_narrative="", action_breakdown=[],
                          previous_action=None, next_action=None, scene_objects=[], environment="sink", evidence=[])


def _place(i):
    return PlaceRecord(place_id=f"p{i}", name=f"places record {i}", zones=[], features=[], first_seen={},
                       last_seen={}, objects_here=[], similarity=0.5, score=_SCORE, evidence=[])


def _pattern(i):
    return PatternRecord(category="habit", pattern_id=f"x{i}", description=f"patterns record {i}", source="s",
                         supporting_episodes=[], confidence=0.5, count=2, evidence=[])


def _search_result(per_kind: int = 3) -> SearchResult:
    return SearchResult(tool="search", participant="P01", arguments={"query": "x"}, routing=[],
                        **{kind: [make(i) for i in range(per_kind)] for kind, make in (
                            ("objects", _object), ("activities", _activity), ("places", _place),
                            ("patterns", _pattern))})


def test_evidence_is_read_round_robin_across_record_kinds():
    items = read_evidence(_search_result(), 6)
    assert [it["kind"] for it in items] == ["objects", "activities", "places", "patterns", "objects", "activities"]
    assert [it["text"] for it in items[:2]] == ["objects record 0", "activities record 0"]
    assert items[1]["video"] == "P01_01" and items[0]["video"] == ""
    # a one-kind result is read in its own rank order
    flat = FlatSearchResult(query="x", results=[FlatHit(kind="activity", video="P01_01", time=1.0, text=f"[P01_01 1s] r{i}",
                                                        similarity=0.5) for i in range(9)])
    assert [it["text"] for it in read_evidence(flat, 4)] == ["r0", "r1", "r2", "r3"]  # time stamps are not evidence
    # fewer records than asked: all of them, nothing invented
    assert len(read_evidence(_search_result(per_kind=1), 6)) == 4


def _pref(pid, subtype, objects, statement, **fields):
    return PreferenceRecord(preference_id=pid, preference=statement, subtype=subtype, keywords=[], objects=objects,
                            context=fields.pop("context", ""), evidence_summary="", confidence=0.5, count=3,
                            supporting_episodes=[], source_videos=[], source="consolidated_preference",
                            processor="deterministic", similarity=fields.pop("similarity", -1), evidence=[], **fields)


PREFS = [
    _pref("h", "habit", ["pan"], "After emptying the pan, usually washes the pan", context="empty pan",
          trigger="empty pan", next_action="wash pan"),
    _pref("s", "storage", ["pan"], "After using the pan, usually puts it on the hob", context="after_use",
          object="pan", preferred_location="hob"),
    _pref("w", "workflow", ["pot", "pan"],
          "Cookware (pot, pan) are usually washed at the sink area, then put on the drying rack", context="cookware",
          use="wash @ sink area", then="put on drying rack"),
]


def test_plans_honour_habit_storage_and_workflow_preferences():
    plan = [_step("empty", "pan", "sink", grounded=True), _step("dry", "pan", "counter", grounded=True)]
    out = apply_preferences(plan, PREFS)
    assert [s["text"] for s in out] == [
        "Empty the pan in the sink",
        "Wash the pan in the sink",          # habit: after emptying the pan, wash it
        "Put the pan at the drying rack",    # workflow: washed cookware goes to the drying rack
        "Dry the pan at the counter",
        "Put the pan at the hob",            # storage: after use, where the person keeps it
    ]
    assert [s.get("preference") for s in out] == [None, "h", "w", None, "s"]


def test_preferences_already_followed_or_about_other_objects_add_nothing():
    plan = [_step("empty", "pan", "sink", grounded=True), _step("wash", "pan", "sink", grounded=True),
            _step("put", "pan", "drying rack", grounded=True), _step("put", "pan", "hob", grounded=True)]
    assert apply_preferences(plan, PREFS) == plan
    other = [_step("cut", "onion", "counter", grounded=True)]
    assert apply_preferences(other, PREFS) == other


def test_offline_planner_uses_retrieved_preferences(embedder):
    policy = OfflinePolicy()
    routine = RoutineRecord(routine_id="r", goal="clean the pan", activity_type="cleanup",
                            canonical_steps=[{"action": "empty pan"}, {"action": "dry pan"}], key_objects=[{"object": "pan"}],
                            supporting_episodes=[], source_videos=[], count=2, confidence=0.5, source="routine_skill",
                            kind="routine_skill", processor="deterministic", similarity=0.9, evidence=[])
    envelope = {"participant": "P01", "arguments": {}}
    calls = [{"name": "get_routine_skill", "arguments": {"goal_query": "clean the pan"},
              "result": RoutinesResult(tool="get_routine_skill", routines=[routine], **envelope)},
             {"name": "get_preferences", "arguments": {"query": "clean the pan"},
              "result": PreferencesResult(tool="get_preferences", **envelope,
                                          preferences=[p.model_copy(update={"similarity": 0.5}) for p in PREFS])}]
    steps = policy.structured_plan("Help P01 clean the pan.", calls)
    assert any(s.get("preference") == "s" and s["location"] == "hob" for s in steps)
    without = policy.structured_plan("Help P01 clean the pan.", calls[:1])
    assert not any(s.get("preference") for s in without) and len(without) < len(steps)


def test_a_responses_queries_are_embedded_in_one_batch_before_its_calls(small_bank):
    bank, _ = small_bank
    view = MemoryView.open(bank, "P37")
    toolset = tool_set("memora", ("search_objects", "search_activities"), "P37", view)
    queries = ["a green chopping board nobody asked about", "rinsing a mug twice", "the kettle near the window"]
    script = [Turn(tool_calls=[tool_call("search_objects", {"query": queries[0]}),
                               tool_call("search_activities", {"query": queries[1]}),
                               tool_call("search_objects", {"query": queries[2]})]), "Answer: E"]
    question = {"question_id": "q", "participant_id": "P37", "qa_type": "SPref", "question": "Which?",
                "choices": ["a", "b", "c", "d", "The information is not available based on the given context"]}
    try:
        with ScriptedServer(script) as server:
            policy = ModelPolicy(get_backend("openai", base_url=server.base_url, model="m"))
            res = run_agent(policy, toolset, "eam_qa", question, "memora")
        encoder = view.encoder
        assert len(res.tool_calls) == 3 and all(c["error"] is None for c in res.tool_calls)
        assert encoder.misses == 0 and encoder.hits == 3  # every call found its query already encoded
    finally:
        toolset.close()


def test_the_reader_asks_typed_tools_round_by_round(embedder):
    from memora_graph.agent.loop import AgentState
    from memora_graph.retrieve import tool_schemas

    names = ["search", "search_objects", "search_activities", "get_routine_skill", "get_preferences"]
    view = {"question_id": "q", "participant_id": "P01", "qa_type": "SHabit",
            "question": "After P01 empties the wok, what do they typically do next?",
            "choices": ["Wipes it", "Rinses it in the sink", "Sets it down", "Stores it", "not available"]}
    policy, state = OfflinePolicy(), AgentState("eam_qa", view)
    first = policy.respond([], tool_schemas(names), forced=False, state=state).tool_calls
    assert [c["function"]["name"] for c in first] == ["get_preferences", "search_activities"]
    assert "empties the wok" in first[1]["function"]["arguments"]
    state.iteration = 1
    second = policy.respond([], tool_schemas(names), forced=False, state=state).tool_calls
    assert [c["function"]["name"] for c in second] == ["search_activities", "get_preferences", "search_objects"]
    # a condition without the typed tools asks the same things through its one search
    flat = policy.respond([], tool_schemas(["search"], "flat1d"), forced=False, state=AgentState("eam_qa", view))
    assert [c["function"]["name"] for c in flat.tool_calls] == ["search"]
