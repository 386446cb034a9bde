"""A plan that starts from the person's own task: when a retrieved task routine (a recurring
task's canonical stages, `consolidate.patterns.canonical`) does the goal, its stages in order are
the draft, grounded in the person's objects, tools and places by `compose.ground`.

A task routine does the goal when every object the goal names is among the routine's goal words
or key objects, and the goal's action (if the goal names one besides make/prepare) is among its
steps. Steps that act on a place as an object ("put down the fridge": taking or putting a
fixture) are left out, and each (action, object) is kept once (no repeated cycles).

`memora plan --from-task` tries the person's own Task rows first (`agent.task_match`), this
module's task routines second. `acts_on_place` / `without_places` are the guard every plan passes
through: no step carries a place.
"""

from __future__ import annotations

from typing import Any

from memora_graph.agent import compose
from memora_graph.agent.evidence import object_classes
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.results import RoutineRecord, ToolResult

FIXTURES = frozenset({"fridge", "cupboard", "drawer", "sink", "tap", "hob", "oven", "counter", "shelf", "bin",
                      "dishwasher", "microwave", "freezer", "cabinet", "rack", "worktop", "top", "table"})
MOVING = frozenset({"take", "put", "insert", "move", "lift", "hold", "carry", "remove"})
GENERIC_GOAL_VERBS = frozenset({"make", "prepare", "cook", "do", "get"})


def task_routines(calls: list[dict[str, Any]]) -> list[RoutineRecord]:
    out: dict[str, RoutineRecord] = {}
    for c in calls:
        res = c.get("result")
        if isinstance(res, ToolResult):
            for _, rec in res.records():
                if isinstance(rec, RoutineRecord) and rec.kind == "task_routine" and rec.steps:
                    out.setdefault(rec.routine_id, rec)
    return list(out.values())


def matching(goal: str, calls: list[dict[str, Any]], lex: Lexicon) -> RoutineRecord | None:
    """The retrieved task routine that does the goal (see the module), most often done first."""
    parts = compose.goal_parts(goal, lex)
    nouns = {o for p in parts for o in p.objects}
    verbs = {p.verb for p in parts if p.verb} - GENERIC_GOAL_VERBS
    if not nouns:
        return None
    best = None
    for r in task_routines(calls):
        have = {n for c in lex.parse(r.goal.split(" (")[0]) for n in c.nouns}
        have |= {n for k in r.key_objects for n in object_classes(k.object, lex)}
        step_verbs = {lex.verb(s.verb) or s.verb for s in r.steps or []}
        if not nouns <= have or (verbs and not verbs & step_verbs and not verbs & {c.verb for c in lex.parse(r.goal)}):
            continue
        if best is None or r.count > best.count:
            best = r
    return best


def draft(r: RoutineRecord, lex: Lexicon) -> list[dict[str, Any]]:
    """The routine's canonical steps as compose's draft steps (before grounding)."""
    proc = compose.routine_procedure(r, lex)
    out, seen = [], set()
    for s in proc.steps:
        if s.verb in MOVING and s.noun.split(":")[0] in FIXTURES:
            continue  # a place is not carried
        key = (s.verb, s.noun)
        if key in seen:
            continue
        seen.add(key)
        out.append({"verb_class": s.verb, "say": s.say, "noun": s.noun, "name": s.name, "place": s.place,
                    "evidence": list(s.evidence), "source": "task", "transferred_from": None})
    return out


def acts_on_place(verb: str, noun: str, lex: Lexicon) -> bool:
    """A step that carries a place as if it were an object ("put down the fridge", "take the
    counter"): its verb moves things and its object is a fixture or furniture."""
    kind = (noun or "").split(":")[0].replace(" ", "_")
    return (lex.verb(verb) or verb) in MOVING and (
        kind in FIXTURES or kind.endswith("_area") or lex.noun_category.get(kind) in ("furniture", "storage"))


def without_places(draft: list[dict[str, Any]], lex: Lexicon, labels: dict[str, str] | None = None
                   ) -> list[dict[str, Any]]:
    """A draft in which no step carries a place (`acts_on_place`): when the step's words (memory's
    name for the object, or the person's label for it in `labels`, noun class -> label) name a
    thing besides the place ("take the pot hob": the pot), the step carries that thing; else it is
    left out ("put down the fridge")."""
    out = []
    for d in draft:
        if not acts_on_place(d["verb_class"], d["noun"], lex):
            out.append(d)
            continue
        words = f"{d.get('name') or ''} {(labels or {}).get(d['noun'], '')}"
        other = [n for n in lex.noun_classes(words) if not acts_on_place(d["verb_class"], n, lex)]
        if other:
            out.append({**d, "noun": other[0], "name": compose.display(other[0])})
    return out
