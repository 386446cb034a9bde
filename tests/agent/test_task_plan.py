"""`memora plan --from-task`: the person's recurring task that does the goal, as the draft."""

from __future__ import annotations

from memora_graph.agent.task_plan import draft, matching
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.results import Action, RoutineRecord, RoutinesResult


def _routine(goal, steps, count=4):
    return RoutineRecord(routine_id=f"P30:task_routine:{goal}", goal=f"{goal} (how it is usually done)",
                         activity_type="task_routine", canonical_steps=[{"action": f"main: {v} {n}"} for v, n in steps],
                         steps=[Action(verb=v, noun=n) for v, n in steps], key_objects=[{"object": n} for _, n in steps],
                         supporting_episodes=["P30_101#t0001"], source_videos=["P30_101"], count=count, confidence=1.0,
                         source="procedure_template", kind="task_routine", processor="deterministic",
                         evidence=["P30:task_routine:x", "P30_101#t0001"])


def test_the_matching_task_gives_the_steps_without_carrying_a_place_or_repeating():
    lex = Lexicon.load()
    coffee = _routine("make coffee", [("open", "cupboard"), ("take", "filter"), ("put", "fridge"), ("pour", "coffee"),
                                      ("turn-on", "coffee maker"), ("pour", "coffee")])
    wash = _routine("wash up knife", [("take", "knife"), ("wash", "knife")], count=9)
    calls = [{"name": "get_routine_skill", "arguments": {}, "result": RoutinesResult(tool="get_routine_skill", participant="P30", arguments={"goal_query": "make coffee", "top_k": 3}, routines=[wash, coffee])}]
    hit = matching("make coffee", calls, lex)
    assert hit is coffee
    steps = [(d["verb_class"], d["noun"]) for d in draft(hit, lex)]
    assert ("put", "fridge") not in steps  # a place is not carried
    assert steps.count(("pour", "coffee")) == 1 and steps[0] == ("open", "cupboard")
    assert matching("make toast", calls, lex) is None  # no task does it: plan as usual
