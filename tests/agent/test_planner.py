"""The offline planner's composition (a learned procedure transferred to the goal's object in its
learned order, procedures chained for a goal of several actions, a preference inserted at the step
it governs, a missing object said to be missing), and `memora plan` over a real bank."""

from __future__ import annotations

import json

from click.testing import CliRunner

from memora_graph.agent.planner import compose_structured, plan, plan_lookups
from memora_graph.cli import main
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.results import (
    ObjectRecord, ObjectsResult, PreferenceRecord, PreferencesResult, RoutineRecord, RoutinesResult,
)

_SCORE = {"vector": 0.5, "fused": 0.01}
_ENVELOPE = {"participant": "P01", "arguments": {}}


def _routine(rid: str, goal: str, steps: list[tuple[str, str, str]], similarity: float = 0.6) -> RoutineRecord:
    """A routine skill as consolidation stores it: canonical steps and their (verb, noun, place)."""
    return RoutineRecord(routine_id=rid, goal=goal, activity_type="meal_preparation",
                         canonical_steps=[{"action": f"{v} {n}"} for v, n, _ in steps],
                         steps=[{"verb": v, "noun": n, "place": p} for v, n, p in steps],
                         key_objects=[{"object": n} for _, n, _ in steps], supporting_episodes=[f"{rid}_ep#t0001"],
                         source_videos=[], count=3, confidence=0.5, source="routine_skill", kind="routine_skill",
                         processor="deterministic", similarity=similarity, evidence=[rid, f"{rid}_ep#t0001"])


def _object(name: str, location: str, color: str = "") -> ObjectRecord:
    return ObjectRecord(object_id=name, entity_id=f"P01:{name}", name=name, kind=name, category="",
                        visual_properties={"color": color} if color else {},
                        spatial_info={"location": location, "place": location, "is_fixture": False},
                        state={"current_state": "", "status": "active"}, places=[], used_with=[],
                        time_seen_seconds={"first": {}, "last": {}}, similarity=0.5, score=_SCORE,
                        evidence=[f"P01:{name}", f"P01_101#t0007"])


def _routines(*routines: RoutineRecord, query: str = "") -> dict:
    return {"name": "get_routine_skill", "arguments": {"goal_query": query, "top_k": 8},
            "result": RoutinesResult(tool="get_routine_skill", routines=list(routines), **_ENVELOPE)}


def _objects(query: str, *objects: ObjectRecord) -> dict:
    return {"name": "search_objects", "arguments": {"query": query, "top_k": 5},
            "result": ObjectsResult(tool="search_objects", results=list(objects), **_ENVELOPE)}


CUT_ONION = _routine("P01:routine:cut", "cut onion", [("take", "knife", "counter"), ("put", "onion", "counter"),
                                                      ("cut", "onion", "counter"), ("put", "knife", "sink")])


def test_a_procedure_is_transferred_to_the_goals_object_in_its_learned_order():
    lex = Lexicon.load()
    calls = [_routines(CUT_ONION, query="cut the cucumber"), _objects("knife", _object("knife", "drawer", "black"))]
    steps = compose_structured("Help P01 cut the cucumber.", calls, lex)
    learned = [s for s in steps if s["source"] == "routine"]
    # the routine's order, the goal's object where the routine had its own, the tool kept
    assert [(s["verb_class"], s["object"]) for s in learned] == [
        ("take", "black knife"), ("put", "cucumber"), ("cut", "cucumber"), ("put", "black knife")]
    assert all("P01:routine:cut" in s["evidence"] for s in learned)
    assert [s.get("learned_on") for s in learned if s["object"] == "cucumber"] == ["learned on the onion"] * 2
    # the person's knife: their name, colour and object record as evidence
    assert "P01:knife" in learned[0]["evidence"] and learned[0]["text"] == "Take the black knife at the counter"
    # memory has no cucumber: said once, on the first step that needs it, not invented
    missing = [s for s in steps if "no cucumber in memory" in s.get("note", "")]
    assert len(missing) == 1 and missing[0]["text"].endswith("(no cucumber in memory)")
    assert steps[0]["verb_class"] == "take" and steps[0]["object"] == "cucumber"  # fetched before it is put down
    # a controller's fields on every step
    assert all({"verb", "object", "place", "preconditions", "evidence"} <= set(s) for s in steps)


def test_routines_are_chained_in_the_goals_order():
    lex = Lexicon.load()
    wash = _routine("P01:routine:wash", "wash plate", [("take", "sponge", "sink"), ("wash", "plate", "sink"),
                                                       ("put", "plate", "drying rack")])
    dry = _routine("P01:routine:dry", "dry plate", [("take", "towel", "counter"), ("dry", "plate", "counter"),
                                                    ("put", "plate", "cupboard")])
    calls = [_routines(dry, wash, query="wash and dry the plate")]
    steps = compose_structured("Help P01 wash and dry the plate.", calls, lex)
    verbs = [s["verb_class"] for s in steps if s["source"] == "routine"]
    assert verbs == ["take", "wash", "put", "take", "dry", "put"]
    assert {s["evidence"][0] for s in steps if s["verb_class"] == "wash"} == {"P01:routine:wash"}
    assert {s["evidence"][0] for s in steps if s["verb_class"] == "dry"} == {"P01:routine:dry"}
    # an action no remembered procedure does is one step from the goal, saying so
    steps = compose_structured("Help P01 wash and fold the plate.", [_routines(wash)], lex)
    assert steps[-1]["verb_class"] == "fold" and "no remembered procedure" in steps[-1]["note"]
    assert steps[-1]["evidence"] == []


def test_a_preference_is_inserted_at_the_step_it_governs():
    lex = Lexicon.load()
    storage = PreferenceRecord(preference_id="P01:pref:knife", preference="After using the knife, usually puts it "
                               "in the drawer", subtype="storage", keywords=[], objects=["knife"], context="after_use",
                               object="knife", preferred_location="drawer", evidence_summary="", confidence=0.6,
                               count=4, supporting_episodes=[], source_videos=[], source="consolidated_preference",
                               processor="deterministic", similarity=0.5, evidence=["P01:pref:knife", "P01_102#t0003"])
    cut = _routine("P01:routine:cut2", "cut onion", [("take", "knife", "counter"), ("cut", "onion", "counter"),
                                                    ("put", "onion", "bowl")])
    prefs = {"name": "get_preferences", "arguments": {"query": "cut the onion"},
             "result": PreferencesResult(tool="get_preferences", preferences=[storage], **_ENVELOPE)}
    steps = compose_structured("Help P01 cut the onion.", [_routines(cut), prefs], lex)
    at = next(i for i, s in enumerate(steps) if s.get("preference") == "P01:pref:knife")
    last_knife = max(i for i, s in enumerate(steps) if "knife" in s["object"] and i != at)
    assert at == last_knife + 1  # right after the last step that uses the knife, not at the end
    assert steps[at]["text"] == "Put down the knife in the drawer"
    assert steps[at]["evidence"] == ["P01:pref:knife", "P01_102#t0003"]
    without = compose_structured("Help P01 cut the onion.", [_routines(cut)], lex)
    assert not any(s.get("preference") for s in without)


def test_the_planner_looks_up_with_the_tools_it_has():
    lex = Lexicon.load()
    full = ["search", "search_objects", "search_activities", "get_routine_skill", "get_preferences"]
    first = plan_lookups("wash and dry the plate", full, [], lex)
    assert [n for n, _ in first] == ["get_routine_skill", "get_preferences", "search_activities"]
    made = [{"name": n, "arguments": a, "result": None} for n, a in first]
    second = plan_lookups("wash and dry the plate", full, made, lex)
    assert [(n, a["goal_query"]) for n, a in second] == [("get_routine_skill", "wash plate"),
                                                          ("get_routine_skill", "dry plate")]
    episodic = plan_lookups("cut the onion", ["search", "search_objects", "search_activities"], [], lex)
    assert [n for n, _ in episodic] == ["search_activities"]
    assert [n for n, _ in plan_lookups("cut the onion", ["search"], [], lex)] == ["search"]


def test_memora_plan_command(small_bank):
    bank, _ = small_bank
    result = plan(bank, "P37", "wash the chicken")
    assert result.steps and any(s["evidence"] for s in result.steps)
    runner = CliRunner()
    r = runner.invoke(main, ["plan", str(bank), "wash the chicken", "--participant", "P37"])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert lines[0] == "Plan for P37: wash the chicken" and lines[1].startswith(" 1. ")
    assert "evidence: " in r.output and "chicken" in r.output
    r = runner.invoke(main, ["plan", str(bank), "wash the chicken", "--participant", "P37", "--json"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.output)
    assert data["goal"] == "wash the chicken" and data["participant"] == "P37"
    assert [s["n"] for s in data["steps"]] == list(range(1, len(data["steps"]) + 1))
    assert all({"text", "verb", "object", "place", "preconditions", "evidence"} <= set(s) for s in data["steps"])
    assert data["calls"][0]["tool"] == "get_routine_skill"
    # a person the bank does not have: a clear error, no traceback
    r = runner.invoke(main, ["plan", str(bank), "wash the chicken", "--participant", "P99"])
    assert r.exit_code != 0 and "Traceback" not in r.output and "P99" in r.output


def test_make_says_what_to_produce_and_the_plan_fetches_the_tools_of_the_work_its_steps_do():
    """EPIC files "make" under cut (its narrations make slices), so "make porridge" planned "Cut the
    porridge". A goal's "make" names no action now, unless another word of it says cut; and for a
    goal naming no work, the tools of the work its steps do are fetched (the knife of a cut), as they
    are for a goal that names the work."""
    from memora_graph.agent import compose

    lex = Lexicon.load()
    assert compose.goal_parts("make porridge", lex)[0].verb is None
    assert compose.goal_parts("make slices of the onion and cut the bread", lex)[0].verb == "cut"
    cut_tomato = _routine("P01:routine:tomato", "cut tomato", [("take", "knife", "drawer"), ("cut", "tomato", "board")])
    cut_onion = _routine("P01:routine:onion", "cut onion", [("take", "knife", "drawer"), ("cut", "onion", "board")])
    porridge = compose_structured("Help P01 make porridge.", [_routines(cut_onion, cut_tomato)], lex)
    assert not any(s["verb_class"] == "cut" for s in porridge)  # nothing remembered makes it: said so, not cut
    sandwich = _routine("P01:routine:sw", "make sandwich", [("take", "bread", "counter"), ("cut", "cheese", "counter"),
                                                            ("put", "cheese", "bread")], similarity=0.9)
    steps = compose_structured("Help P01 make a cheese sandwich.", [_routines(sandwich, cut_onion, cut_tomato)], lex)
    said = [(s["verb_class"], s["object"]) for s in steps]
    assert ("take", "knife") in said and said.index(("take", "knife")) < said.index(("cut", "cheese"))
