"""The offline planner: the lookups it makes for a goal, the plan it composes from their results,
and `plan()`, the same planner over a bank without the agent loop (`memora plan`, the MCP `plan`
tool).

Lookups (`plan_lookups`), with whatever tools the memory offers, in rounds of at most three calls:
routines for the whole goal, the person's preferences about it and the episodes most like it;
then, for a goal of several actions ("wash, cut and stir-fry the bok choy"), routines (or
episodes) for each action; then the objects the draft plan needs, in the entity tools. The plan
itself is `agent.compose` (procedures adapted and chained, objects grounded) followed by
`apply_preferences`. Each step is structured for a controller: verb, object, place,
preconditions, the evidence ids it came from, and a note where memory lacks what it needs.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from memora_graph.agent import compose, task_match, task_plan
from memora_graph.consolidate.vocab import past_tense
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.results import PreferenceRecord
from memora_graph.retrieve.tasks import TaskIndex
from memora_graph.text import KITCHEN_NOUNS, tokenize

MAX_STEPS = compose.MAX_STEPS
MAX_PLAN_STEPS = 15  # what a plan answer is read to (bench.answers.extract_plan)
# The benchmark's offline policy composes (its goals are replays of one video's moments and transfers
# to new objects: on P01-P03 task-first lowered Replay RGP .576 -> .517 and Generalize .523 -> .478,
# docs/planning.md, "Plans from tasks"). A person's own goal (`memora plan`, the server's plan tool)
# starts from their task that does it, when one does (`plan(..., from_task=True)`, the default).
TASK_FIRST = False
MAX_TASK_PLAN_STEPS = 40  # a plan from one of the person's tasks (`memora plan`): the whole task, focused (P30's coffee: 37 steps)
MAX_PREFERENCES = 6  # retrieved preferences considered for one plan
MAX_PREFERENCE_STEPS = 4  # steps a plan may gain from them
ROUTINES_K = 8  # routines retrieved for the whole goal
PART_ROUTINES_K = 3  # for one of its actions
EPISODES_K = 10
PREFERENCES_K = 8
OBJECTS_K = 5
MAX_PARTS = 3  # actions of a goal looked up one by one
MAX_OBJECT_LOOKUPS = 6
_KITCHEN = frozenset(KITCHEN_NOUNS)


# -- lookups ---------------------------------------------------------------------------------------

def _key(name: str, args: dict[str, Any]) -> str:
    return f"{name}:{json.dumps(args, sort_keys=True)}"


def plan_lookups(goal: str, tools: list[str], calls: list[dict[str, Any]], lex: Lexicon) -> list[tuple[str, dict[str, Any]]]:
    """The next round of (tool, arguments) for `goal` given the calls made so far; [] when the plan
    can be written. Uses only the advertised `tools`."""
    has = set(tools).__contains__
    made = {_key(c["name"], c["arguments"] if isinstance(c["arguments"], dict) else {}) for c in calls}

    def fresh(wanted: list[tuple[str, dict[str, Any]]]) -> list[tuple[str, dict[str, Any]]]:
        return [(n, a) for n, a in dict((_key(n, a), (n, a)) for n, a in wanted).values() if _key(n, a) not in made]

    def episodes(q: str, k: int) -> tuple[str, dict[str, Any]] | None:
        if has("search_activities"):
            return "search_activities", {"query": q, "top_k": k}
        if has("search"):
            return "search", {"query": q}
        return None

    first: list[tuple[str, dict[str, Any]]] = []
    if has("get_routine_skill"):
        first.append(("get_routine_skill", {"goal_query": goal, "top_k": ROUTINES_K}))
    if has("get_preferences"):
        first.append(("get_preferences", {"query": goal, "top_k": PREFERENCES_K}))
    call = episodes(goal, EPISODES_K)
    if call:
        first.append(call)
    todo = fresh(first)
    if not calls:
        return todo[:3]
    parts = compose.goal_parts(goal, lex)
    per_part: list[tuple[str, dict[str, Any]]] = []
    if len(parts) > 1:
        for p in parts[:MAX_PARTS]:
            q = " ".join(x for x in (p.verb or "", *(p.words.get(o, compose.display(o)) for o in p.objects[:1])) if x)
            if has("get_routine_skill"):
                per_part.append(("get_routine_skill", {"goal_query": q, "top_k": PART_ROUTINES_K}))
            elif (call := episodes(q, EPISODES_K)) is not None:
                per_part.append(call)
    todo = fresh(per_part)
    if todo:
        return todo[:3]
    objects = compose.objects_to_ground(goal, calls, lex, MAX_OBJECT_LOOKUPS)
    lookups: list[tuple[str, dict[str, Any]]] = []
    for o in objects:
        if has("search_objects"):
            lookups.append(("search_objects", {"query": o, "top_k": OBJECTS_K}))
        elif has("get_object_history"):
            lookups.append(("get_object_history", {"object_query": o}))
        elif has("search") and o != goal:
            lookups.append(("search", {"query": o}))
    done = sum(1 for c in calls if c["name"] in ("search_objects", "get_object_history")
               or (c["name"] == "search" and c["arguments"].get("query") in objects))
    return fresh(lookups)[:max(0, min(3, MAX_OBJECT_LOOKUPS - done))]


# -- the plan --------------------------------------------------------------------------------------

def compose_structured(task_query: str, calls: list[dict[str, Any]], lex: Lexicon,
                       from_task: bool = False, tasks: TaskIndex | list[dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """Structured steps for a goal from the calls' results (see the module docstring); the plan from
    the request alone (`generic_plan`) when memory returned no procedure for it.

    `from_task`: start from the person's task that does the goal, when one does: one of `tasks`
    (their Task rows, `agent.task_match`), else a retrieved recurring task routine
    (`agent.task_plan`); compose only when no single task fits. Whatever the draft, a step that
    carries a place as an object ("put down the fridge") is left out."""
    goal = task_text(task_query)
    draft = None
    limit = MAX_PLAN_STEPS
    if from_task:
        hit = task_match.best(goal, tasks if tasks is not None else [], lex)
        if hit is not None:
            draft, limit = task_match.draft(*hit, lex), MAX_TASK_PLAN_STEPS
        elif (task := task_plan.matching(goal, calls, lex)) is not None:
            draft = task_plan.draft(task, lex)
    if not draft:
        draft = compose.compose(goal, calls, lex)
    found = compose.groundings(calls, lex)
    draft = task_plan.without_places(draft, lex, {n: g.label for n, g in found.items()})
    if not draft:
        return generic_plan(task_query)
    for d in draft:  # a task's object is one the person handled in it, whatever the entity lookups found
        if d["source"] == "task" and d["noun"] and d["noun"] not in found:
            found[d["noun"]] = compose.Grounding(d["name"], d["name"], "", d["evidence"][-1:])
    goal_objects = {o for p in compose.goal_parts(goal, lex) for o in p.objects}
    steps = compose.ground(draft, found, goal_objects, memory=bool(calls), general=lambda n: compose._general(n, lex))
    prefs = relevant_preferences(goal, calls, steps)
    if limit == MAX_PLAN_STEPS:
        return apply_preferences(steps, prefs, say=compose._say)[:limit]
    # a task's plan: a preference adds no step the task already does (the task's own stays, in its place)
    done = {(s["verb"], s["object"]) for s in steps}
    out = apply_preferences(steps, prefs, say=compose._say, limit=limit + MAX_PREFERENCE_STEPS)
    return [s for s in out if not s.get("preference") or (s["verb"], s["object"]) not in done][:limit]


def plan_text(steps: list[dict[str, Any]]) -> str:
    """The plan as the agent answers it: numbered steps after "Plan:", then each step's evidence."""
    lines = ["Plan:", *(f"{i}. {s['text']}" for i, s in enumerate(steps, 1))]
    cited = [f"{i}: {', '.join(s['evidence'][:4])}" for i, s in enumerate(steps, 1) if s.get("evidence")]
    if cited:
        lines += ["", "Evidence: " + "; ".join(cited)]
    return "\n".join(lines)


def relevant_preferences(query: str, calls: list[dict[str, Any]], steps: list[dict[str, Any]]) -> list[PreferenceRecord]:
    """The retrieved preferences that concern this plan: one of their objects is an object of the
    plan or of the request; best retrieval similarity first."""
    prefs = compose.preferences_of(calls)
    nouns = {w for s in steps for w in str(s["entity"]).split()} | set(re.findall(r"[a-z]+", query.lower()))
    relevant: dict[str, PreferenceRecord] = {}
    for p in sorted(prefs, key=lambda p: -float(p.similarity or 0)):
        if any(w in nouns for o in p.objects for w in o.lower().split()):
            relevant.setdefault(p.preference_id, p)
    return list(relevant.values())[:MAX_PREFERENCES]


def _step(action: str, entity: str, location: str, *, grounded: bool, preference: str | None = None,
          evidence: list[str] | None = None) -> dict[str, Any]:
    step = {"action": action, "entity": entity, "location": location, "grounded": grounded,
            "text": f"{action.capitalize()} the {entity} {_prep(location)} the {location}"}
    if preference:
        step["preference"] = preference
    if evidence is not None:  # a composed plan's step: the controller's fields too
        step.update(verb=action, object=entity, place=location, preconditions=[], evidence=list(evidence),
                    source="preference" if preference else "goal")
    return step


def _prep(location: str) -> str:
    return "in" if location.split()[-1:] and location.split()[-1] in ("sink", "drawer", "cupboard", "fridge", "bin",
                                                                     "box", "bag", "basket") else "at"


def _matches(step: dict[str, Any], obj: str, verb: str | None = None) -> bool:
    entity = str(step["entity"]).lower()
    if not obj or not any(w in entity.split() for w in obj.lower().split()):
        return False
    return verb is None or tokenize(verb) <= tokenize(step["action"]) or tokenize(step["action"]) <= tokenize(verb)


def _after_words(text: str | None) -> str:
    """"put on drying rack" -> "drying rack": the place a workflow's follow-up puts things."""
    words = (text or "").split(" ", 2)
    return words[2] if len(words) == 3 and words[0] == "put" and words[1] in ("in", "on", "at", "into") else ""


def apply_preferences(steps: list[dict[str, Any]], prefs: list[PreferenceRecord],
                      say: Callable[[str], str] | None = None, limit: int = MAX_STEPS + MAX_PREFERENCE_STEPS
                      ) -> list[dict[str, Any]]:
    """Honour retrieved preferences in a plan, the way a person's helper would, reading each
    preference's structured fields:

    - storage (object, preferred location; context storage, after use or default): after the last
      step with the object, put it back where the person keeps it (unless the plan already does);
    - habit (trigger, next action: "empty pan" -> "wash pan"): after a step that does the trigger,
      add the habitual next action (unless it already follows);
    - workflow (objects, use "wash @ sink", then "put on drying rack"): after the plan uses one of
      those objects that way, add the follow-up.

    Each added step names the preference it honours; at most MAX_PREFERENCE_STEPS are added. With
    `say` (a composed plan's verb words: "put" is said "place"), added steps carry the structured
    fields and the preference's evidence ids."""
    out = list(steps)
    composed = say is not None
    say = say or (lambda verb: verb)
    added = 0
    for p in prefs:
        if added >= MAX_PREFERENCE_STEPS:
            break
        objects = [o.lower().replace("_", " ") for o in p.objects]
        new: tuple[int, dict[str, Any]] | None = None
        ev = list(p.evidence[:3]) if composed else None
        if p.subtype == "storage" and objects and p.preferred_location and p.context != "during_use":
            place = p.preferred_location.strip(" .").lower()
            idx = [i for i, s in enumerate(out) if _matches(s, objects[0])]
            if idx and not any(_matches(s, objects[0]) and s["location"] == place for s in out):
                new = (idx[-1] + 1, _step(say("put"), out[idx[-1]]["entity"], place, grounded=True,
                                          preference=p.preference_id, evidence=ev))
        elif p.subtype == "habit":
            trigger, nxt = (p.trigger or "").split(), (p.next_action or "").split()
            if len(trigger) >= 2 and len(nxt) >= 2:
                idx = [i for i, s in enumerate(out) if _matches(s, " ".join(trigger[1:]), trigger[0])]
                if idx:
                    i = idx[0]
                    verb, obj = nxt[0], " ".join(nxt[1:])
                    follow = out[i + 1] if i + 1 < len(out) else None
                    if follow is None or not _matches(follow, obj, verb):
                        new = (i + 1, _step(say(verb), obj, out[i]["location"], grounded=True,
                                            preference=p.preference_id, evidence=ev))
        elif p.subtype == "workflow" and objects and p.use and (place := _after_words(p.then)):
            # the use is matched on its participle ("washed"), the word the statement uses
            used = past_tense(p.use.split(" @ ")[0])
            idx = [i for i, s in enumerate(out) if re.fullmatch(r"\w+", used) and any(_matches(s, o, used) for o in objects)]
            place = place.strip(" .").lower()
            if idx and not any(s["location"] == place for s in out[idx[-1] + 1:]):
                i = idx[-1]
                new = (i + 1, _step(say("put"), out[i]["entity"], place, grounded=True, preference=p.preference_id,
                                    evidence=ev))
        if new is not None:
            out.insert(*new)
            added += 1
    return out[:limit]


_HELP = re.compile(r"^\s*help\s+(?:p\d+|the participant|the person)\s+(?:to\s+)?", re.I)


def task_text(task_query: str) -> str:
    """The goal of a planning request ("Help P01 cut the onion." -> "cut the onion")."""
    return _HELP.sub("", task_query).strip().rstrip(".")


def generic_plan(task_query: str) -> list[dict[str, Any]]:
    """A plan from the request alone (Parametric, or nothing retrieved): locate, take, act, put back."""
    query = task_text(task_query).lower()
    nouns = [w for w in re.findall(r"[a-z]+", query) if w in _KITCHEN] or [re.findall(r"[a-z]+", query)[-1] if query else "item"]
    noun = nouns[0]
    verbs = [w for w in re.findall(r"[a-z]+", query) if w in ("wash", "dry", "cut", "peel", "stir", "pour", "rinse", "wipe",
                                                               "fry", "boil", "chop", "slice", "mix", "fill", "open", "close")]
    verbs = verbs or ["prepare"]
    steps = [("take", noun, "counter")]
    for v in verbs:
        steps.append((v, noun, "sink" if v in ("wash", "rinse", "dry", "fill") else "counter"))
    steps.append(("place", noun, "counter"))
    return [_step(a, e, loc, grounded=False) for a, e, loc in steps]


# -- the planner over a bank (`memora plan`, the MCP tool) ------------------------------------------

MAX_ROUNDS = 6  # lookup rounds before the plan is written (the agent loop allows planning 8 iterations)


@dataclass
class PlanResult:
    goal: str
    participant: str
    steps: list[dict[str, Any]]  # structured: verb, object, place, preconditions, evidence, text, note
    calls: list[dict[str, Any]] = field(default_factory=list)  # {tool, arguments}

    @property
    def text(self) -> str:
        return plan_text(self.steps)

    def as_dict(self) -> dict[str, Any]:
        keys = ("text", "verb", "verb_class", "object", "place", "preconditions", "evidence", "grounded", "source",
                "note", "learned_on", "preference")
        steps = []
        for i, s in enumerate(self.steps, 1):
            row = {"n": i, **{k: s[k] for k in keys if k in s}}
            row.setdefault("verb", s.get("action", ""))
            row.setdefault("object", s.get("entity", ""))
            row.setdefault("place", s.get("location", ""))
            row.setdefault("preconditions", [])
            row.setdefault("evidence", [])
            steps.append(row)
        return {"goal": self.goal, "participant": self.participant, "steps": steps, "calls": self.calls}


def plan(bank: str | Path, participant: str, goal: str, memory: str = "memora", from_task: bool = True
         ) -> PlanResult:
    """A plan for `goal` from `participant`'s memory in `bank` (the offline planner's lookups and
    composition, without the agent loop). `memory` picks the representation the tools read.
    `from_task`: start from the person's own task that does the goal, when one does; compose only
    when none fits (False: always compose, as the benchmark's offline policy does)."""
    from memora_graph.limits import check_text
    from memora_graph.retrieve.registry import get_family

    check_text(goal, "the goal")
    store = get_family(memory).open(Path(bank), participant)
    try:
        return plan_memory(store, participant, goal, memory, from_task=from_task)
    finally:
        closer = getattr(store, "close", None)
        if closer is not None:
            closer()


def plan_memory(store, participant: str, goal: str, memory: str = "memora", from_task: bool = True
                ) -> PlanResult:
    """`plan` over a memory already open (a server plans many goals from one open bank)."""
    from memora_graph.limits import check_text
    from memora_graph.retrieve.registry import tool_names, tool_set

    check_text(goal, "the goal")
    lex = Lexicon.load()
    names = tool_names(memory, advertised_only=False)
    tools = tool_set(memory, names, participant, store)
    calls: list[dict[str, Any]] = []
    target = task_text(goal)
    for _ in range(MAX_ROUNDS):
        round_ = plan_lookups(target, names, calls, lex)
        if not round_:
            break
        tools.prefetch(round_)
        for name, args in round_:
            calls.append({"name": name, "arguments": args, "result": tools.call(name, args)})
    tasks = task_match.read_tasks(store) if from_task else []
    steps = compose_structured(goal, calls, lex, from_task=from_task, tasks=tasks)
    return PlanResult(goal, participant, steps, [{"tool": c["name"], "arguments": c["arguments"]} for c in calls])
