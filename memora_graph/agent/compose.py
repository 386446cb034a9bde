"""Plans composed from what a person remembers, for goals memory has seen and goals it has not.

A goal ("peel, chop and stir-fry the onion") is read into parts, each an action and its objects as
EPIC verb and noun classes (`perceive.lexicon`): peel onion, cut onion, cook onion. Every retrieved
procedure is read the same way, step by step: a routine skill's canonical steps (verb, noun, place
as consolidation recorded them) or one remembered episode's actions. Then, per part, in the goal's
order:

- a procedure that does the part's action to the part's object is used as it was learned (a
  routine the person repeats is preferred to one episode);
- failing that, a procedure that does the action to another object is *transferred*: the object it
  was learned on (the noun of its first step with that action) is replaced by the goal's object in
  every step, the other objects (tools, containers) and the order kept;
- parts the same procedure already covers are not planned twice; procedures for successive parts
  are *chained* in the goal's order (a step that repeats the one before it is dropped);
- a part no remembered procedure does becomes one step from the goal itself, saying so;
- the part's object is fetched first unless the procedure takes it, and the tools the person
  handles around that action in two or more procedures are taken up before it (`with_tools`).

Objects are then grounded in the person's memory (their name, colour, material and where it is
kept, from the entity tools); an object the goal names that memory has no record of keeps the
goal's word and the step says "not in memory". Finally the person's preferences are inserted at
the steps they govern (`apply_preferences`: where an object is put back, a habitual next action,
a workflow's follow-up), each naming the preference. Every step carries the evidence ids it came
from (routine, episode segments, object, preference) and preconditions a controller can check.

Everything here reads typed tool results only; nothing reads a task's references.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Any

from memora_graph.agent.claims import is_task_record
from memora_graph.baselines.flat1d import FlatHit
from memora_graph.baselines.graph2d import GraphNode
from memora_graph.consolidate.vocab import FILLER
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.results import (
    ActivityRecord, ObjectRecord, PreferenceRecord, RoutineRecord, ToolResult, VisibleObject,
)

MAX_STEPS = 12  # steps from procedures (preferences may add MAX_PREFERENCE_STEPS more)
MIN_PART_STEPS = 4  # a chained part keeps at least this many of its procedure's steps
ROUTINE_BONUS = 0.25  # a repeated routine is preferred to one episode that matches as well
COVERAGE = 0.5  # ... and one that names more of the goal's objects
LENGTH = 0.05  # ... and a longer one (per step, up to 8): it shows more of how
MAX_TOOLS = 2  # tools a part may gain from the procedures that do its action
GENERIC_VERBS = frozenset({"prepare", "make", "do", "use", "finish"})  # they say what, not how
SET_CATEGORIES = ("crockery", "cutlery", "cookware", "utensils", "containers")  # things set out or washed one by one
TOOL_CATEGORIES = ("utensils", "cutlery", "cookware", "cleaning equipment and material", "containers")
# verb classes rendered with the word a helper would say (the class key is the annotators' word)
_SAY = {"put": "put down", "put-down": "put down", "pick-up": "pick up", "take": "take", "turn-on": "turn on",
        "turn-off": "turn off", "put-in": "put down", "put-into": "put down", "put-on": "put down", "put-onto": "put down",
        "move-into": "move", "move-onto": "move", "take-out": "take out", "cook": "cook"}
_PARTICLES = frozenset({"up", "down", "on", "off", "out", "in", "into", "onto"})
_IN_PLACES = ("sink", "drawer", "cupboard", "fridge", "bin", "box", "bag", "basket", "cabinet", "oven", "microwave",
              "dishwasher", "pan", "pot", "wok", "bowl", "saucepan")


@dataclass
class GoalPart:
    """One action of the goal: its verb class, its objects' classes and the goal's own words."""

    verb: str | None
    objects: list[str]
    words: dict[str, str] = field(default_factory=dict)  # class -> the goal's word for it
    instrument: str | None = None
    place: str = ""  # where the goal says the action happens or ends ("the table")


@dataclass
class ProcStep:
    verb: str  # class
    say: str  # the verb as said in a step
    noun: str  # class ("" when the step has none)
    name: str  # the object as memory names it
    place: str
    evidence: list[str]


@dataclass
class Procedure:
    kind: str  # routine | episode
    goal: str
    steps: list[ProcStep]
    evidence: list[str]
    similarity: float
    source_id: str
    goal_verbs: list[str] = field(default_factory=list)  # a routine's goal, read as classes
    goal_nouns: list[str] = field(default_factory=list)


@dataclass
class Grounding:
    name: str
    label: str
    location: str
    evidence: list[str]


def display(noun_class: str) -> str:
    """An EPIC noun class as words ("pepper:bell" -> "bell pepper")."""
    return " ".join(reversed(noun_class.split(":"))).replace("_", " ") if noun_class else ""


def _say(verb_word: str) -> str:
    w = verb_word.lower().strip()
    if w in _SAY:
        return _SAY[w]
    first, _, particle = w.partition("-")
    return f"{first} {particle}" if particle in ("up", "off", "out") else first


def _place(text: str | None) -> str:
    return re.sub(r"\s*\(.*$", "", (text or "").replace("_", " ")).strip()


# -- the goal --------------------------------------------------------------------------------------

def goal_parts(goal: str, lex: Lexicon) -> list[GoalPart]:
    """The goal's actions in order, each with its objects; an action with no object of its own takes
    the objects of the one before it ("wash the dishes, dry them"), or, first in the goal, of the
    next one that has some ("peel, chop and fry the onion")."""
    parts: list[GoalPart] = []
    said = goal_words(goal, lex)
    made = _makes(goal, lex)
    for c in lex.parse(goal):
        if c.negated:
            continue
        if made and c.verb == made:  # "make porridge": no cut (EPIC files "make" under it); what, not how
            c = replace(c, verb=None)
        # things carried; failing those, the fixtures, head noun first ("the kitchen countertop")
        objs = [n for n in c.objects() if _carried(n, lex)] or list(reversed(c.objects()))
        verb = c.verb
        if c.instrument and objs and all(lex.noun_category.get(n) == lex.noun_category.get(c.instrument) or
                                         lex.noun_category.get(n) in SET_CATEGORIES and
                                         lex.noun_category.get(c.instrument) in SET_CATEGORIES for n in objs):
            objs = [c.instrument, *objs]  # "with plate, bowl and cutlery": one list, not a tool
        elif c.instrument and (verb in GENERIC_VERBS or not verb) and _carried(c.instrument, lex):
            # "prepare a salad using vegetables": what memory shows done with the ingredient
            objs, verb = [c.instrument], None
        places = [n for n in c.nouns if n not in objs and n != c.instrument]
        words = {n: said.get(n, display(n)) for n in c.nouns}
        place = c.place or (places[0] if places else "")
        parts.append(GoalPart(verb, objs, words, c.instrument, words.get(place, display(place)) if place else ""))
    for i, p in enumerate(parts):
        if p.objects:
            continue
        prev = next((q for q in reversed(parts[:i]) if q.objects), None)
        nxt = next((q for q in parts[i + 1:] if q.objects), None)
        src = prev or nxt
        if src is not None:
            p.objects, p.words = list(src.objects), dict(src.words)
    parts = [p for p in parts if p.verb or p.objects]
    specific = [p for p in parts if p.verb not in GENERIC_VERBS]
    return specific or parts  # "wash the cucumber before preparing it": the washing is the plan


def _makes(goal: str, lex: Lexicon) -> str | None:
    """The verb class a goal's "make" was read as ("cut": EPIC's narrations make slices), when no other
    word of the goal says that class ("make a sandwich", not "make slices and cut the bread")."""
    words = re.findall(r"[a-z]+", goal.lower())
    if "make" not in words:
        return None
    cls = lex.verb("make")
    return None if any(w != "make" and lex.verb(w) == cls for w in words) else cls


def goal_words(goal: str, lex: Lexicon) -> dict[str, str]:
    """noun class -> the goal's own word(s) for it ("table", not the class key "top")."""
    words = re.findall(r"[a-z]+", goal.lower())
    out: dict[str, str] = {}
    for n in (2, 1):
        for i in range(len(words) - n + 1):
            if n == 2 and (lex.noun_classes(words[i]) or lex.noun_classes(words[i + 1])):
                continue  # a two-word name only where neither word names a thing alone ("bok choy")
            phrase = " ".join(words[i:i + n])
            found = lex.noun_classes(phrase)
            if len(found) == 1:
                out.setdefault(found[0], phrase)
    return out


# -- procedures from tool results -------------------------------------------------------------------

def _first_noun(text: str, lex: Lexicon) -> str:
    found = lex.noun_classes(text)
    return found[0] if found else ""


def routine_procedure(r: RoutineRecord, lex: Lexicon) -> Procedure:
    ids = [r.routine_id, *r.supporting_episodes[:2]]
    steps: list[ProcStep] = []
    typed = r.steps if r.steps and len(r.steps) == len(r.canonical_steps) else None
    for i, s in enumerate(r.canonical_steps):
        words = s.action.split()
        if not words:
            continue
        if typed is not None:
            verb, noun, place = typed[i].verb, typed[i].noun or "", typed[i].place or ""
        else:
            clause = (lex.parse(s.action) or [None])[0]
            verb = (clause.verb if clause else None) or words[0]
            noun, place = (clause.objects()[0] if clause and clause.objects() else ""), ""
        vclass = lex.verb(verb) or verb
        name = " ".join(words[1:]) if typed is None or not typed[i].noun else typed[i].noun
        steps.append(ProcStep(vclass, _say(words[0] if not typed else verb), _first_noun(name, lex) or noun,
                              name.replace("_", " "), _place(place), ids))
    clauses = lex.parse(r.goal)
    return Procedure("routine", r.goal, steps, list(r.evidence), float(r.similarity or 0), r.routine_id,
                     [c.verb for c in clauses if c.verb], [n for c in clauses for n in c.objects()])


def _text_steps(text: str, place: str, ids: list[str], lex: Lexicon) -> list[ProcStep]:
    steps = []
    for part in re.split(r"[;.]\s*", re.sub(r"^\[[^\]]*\]\s*", "", text)):
        part = re.sub(r"\(\+\d+ more\)", "", part).strip()
        if not part:
            continue
        for c in lex.parse(part):
            if not c.verb or c.negated:
                continue
            objs = c.objects()
            noun = objs[0] if objs else ""
            words = part.lower().split()
            head = "-".join(words[:2]) if len(words) > 1 and words[1] in _PARTICLES else (words[0] if words else "")
            said = head if lex.verb(head.split("-")[0]) == c.verb or lex.verb(head) == c.verb else c.verb
            steps.append(ProcStep(c.verb, _say(said), noun, display(noun),
                                  _place(place) or display(c.place or ""), ids))
    return steps


def episode_procedure(rec: Any, kind: str, lex: Lexicon) -> Procedure | None:
    """One remembered episode's actions as a procedure (MEMORA's activity records, a Flat-1D text
    record, a Graph-2D activity node)."""
    if isinstance(rec, ActivityRecord):
        ids = list(rec.evidence or [rec.segment_id])[:2]
        place = _place(rec.environment)
        steps = []
        for a in rec.action_breakdown:
            verb = lex.verb(a.action) or lex.verb(a.action.split("-")[0])
            if not verb:
                continue
            noun = _first_noun(a.object, lex) if a.object else ""
            steps.append(ProcStep(verb, _say(a.action), noun, (a.object or "").replace("_", " "), place, ids))
        if not steps:
            steps = _text_steps(rec.summary, place, ids, lex)
        return Procedure("episode", rec.summary, steps, ids, float(rec.similarity or 0), rec.segment_id) if steps else None
    if isinstance(rec, FlatHit) and rec.kind == "activity":
        ids = [f"{rec.video}@{rec.time:g}s"]
        steps = _text_steps(rec.text(), "", ids, lex)
        return Procedure("episode", rec.text(), steps, ids, float(rec.similarity or 0), ids[0]) if steps else None
    if isinstance(rec, GraphNode) and kind == "activities":
        ids = [rec.id]
        steps = _text_steps(rec.text(), rec.place or "", ids, lex)
        return Procedure("episode", rec.text(), steps, ids, float(rec.similarity or 0), rec.id) if steps else None
    return None


def procedures(calls: list[dict[str, Any]], lex: Lexicon) -> list[Procedure]:
    """Every routine and episode the calls retrieved, once each, in retrieval order."""
    out: dict[str, Procedure] = {}
    for c in calls:
        result = c.get("result")
        if not isinstance(result, ToolResult):
            continue
        for kind, rec in result.records():
            if is_task_record(rec):  # a task's stages are planned from only with `plan --from-task` (task_plan.py)
                continue
            if isinstance(rec, RoutineRecord) and rec.canonical_steps:
                p = routine_procedure(rec, lex)
            else:
                p = episode_procedure(rec, kind, lex)
            if p is not None and p.steps:
                prev = out.get(p.source_id)
                if prev is None or p.similarity > prev.similarity:
                    out[p.source_id] = p
    return list(out.values())


# -- choosing and adapting procedures -------------------------------------------------------------

def _same_kind(a: str, b: str, lex: Lexicon) -> bool:
    cat = lex.noun_category.get(a)
    return bool(cat) and cat == lex.noun_category.get(b)


def _general(noun: str, lex: Lexicon) -> bool:
    """A class that names its whole kind ("vegetable", "fruit", "cutlery"): any of that kind is one."""
    return bool(noun) and display(noun) in lex.noun_category.get(noun, "")


def part_score(proc: Procedure, part: GoalPart, lex: Lexicon) -> tuple[float, str | None]:
    """How well a procedure does a goal part, and the object to substitute (None: as learned).
    0 when it never does the part's action (or, for a part with no action, never its object)."""
    verbs = [s.verb for s in proc.steps] + proc.goal_verbs
    nouns = {s.noun for s in proc.steps if s.noun} | set(proc.goal_nouns)
    base = proc.similarity + (ROUTINE_BONUS if proc.kind == "routine" else 0.0)
    if part.verb and part.verb not in verbs:
        return 0.0, None
    if not part.objects:
        return 1.0 + base, None
    hit = [o for o in part.objects if o in nouns or (_general(o, lex) and any(_same_kind(o, n, lex) for n in nouns))]
    if hit:
        return 2.0 + len(hit) / len(part.objects) + base, None
    if not part.verb:
        return 0.0, None
    theme = next((s.noun for s in proc.steps if s.verb == part.verb and s.noun), "")
    if not theme:
        return 0.5 + base, None
    # transfer: learned on another object; one of the same kind (vegetable, cutlery) transfers best
    return (1.5 if _same_kind(theme, part.objects[0], lex) else 1.0) + base, theme


def adapt(proc: Procedure, part: GoalPart, theme: str | None) -> list[dict[str, Any]]:
    """The procedure's steps for a part: as learned, or with the goal's object for `theme`."""
    out = []
    target = part.objects[0] if part.objects else ""
    for s in proc.steps:
        noun, name, note = s.noun, s.name, None
        if theme and s.noun == theme and target:
            noun, name = target, part.words.get(target, display(target))
            note = f"learned on the {s.name}" if s.name else None
        out.append({"verb_class": s.verb, "say": s.say, "noun": noun, "name": name, "place": s.place,
                    "evidence": list(s.evidence), "source": proc.kind, "transferred_from": note})
    return out


def _trim(steps: list[dict[str, Any]], part: GoalPart, budget: int) -> list[dict[str, Any]]:
    """At most `budget` steps of a procedure, kept around its first step that does the part."""
    if len(steps) <= budget:
        return steps
    at = next((i for i, s in enumerate(steps) if s["verb_class"] == part.verb), 0)
    start = max(0, min(at - 1, len(steps) - budget))
    return steps[start:start + budget]


def compose(goal: str, calls: list[dict[str, Any]], lex: Lexicon) -> list[dict[str, Any]]:
    """Draft steps (before grounding and preferences) for a goal from the calls' procedures:
    each {verb_class, say, noun, name, place, evidence, source, transferred_from, note}."""
    parts = goal_parts(goal, lex)
    procs = procedures(calls, lex)
    if not parts or not procs:
        return []
    goal_nouns = {o for p in parts for o in p.objects}
    chosen: list[tuple[GoalPart, Procedure | None, str | None]] = []
    used: set[str] = set()
    for part in parts:
        ranked = []
        for i, p in enumerate(procs):
            score, theme = part_score(p, part, lex)
            if score > 0:  # a procedure that covers more of the goal, and shows more of how, first
                covered = goal_nouns & ({s.noun for s in p.steps} | set(p.goal_nouns))
                score += COVERAGE * len(covered) / max(1, len(goal_nouns)) + LENGTH * min(len(p.steps), 8)
            ranked.append((score, i, theme, p))
        score, _, theme, proc = min(ranked, key=lambda x: (-x[0], x[1]))
        if score <= 0:
            chosen.append((part, None, None))
        elif proc.source_id in used:
            continue  # the procedure chosen for an earlier part does this one too
        else:
            used.add(proc.source_id)
            chosen.append((part, proc, theme))
    n = max(1, sum(1 for _, proc, _ in chosen if proc is not None))
    budget = max(MIN_PART_STEPS, MAX_STEPS // n)
    out: list[dict[str, Any]] = []
    for part, proc, theme in chosen:
        carried = [o for o in part.objects if _carried(o, lex)]
        # "with plate, bowl and cutlery": the action for each object in turn
        if len(carried) > 1 and all(lex.noun_category.get(o) in SET_CATEGORIES for o in carried):
            out.extend(_each(part, proc, carried, lex))
            continue
        out.extend(_fetch(part, proc, theme, lex))
        if proc is None:
            obj = part.objects[0] if part.objects else ""
            out.append({"verb_class": part.verb or "", "say": _say(part.verb or "prepare"), "noun": obj,
                        "name": part.words.get(obj, display(obj)), "place": part.place, "evidence": [],
                        "source": "goal", "transferred_from": None, "note": "no remembered procedure for this action"})
            continue
        steps = _trim(adapt(proc, part, theme), part, budget)
        # the tools of the part's action; for a part naming none ("make a sandwich"), of the work its steps do
        work = [part.verb] if part.verb else dict.fromkeys(st["verb_class"] for st in steps
                                                           if st["verb_class"] not in FILLER)
        for verb in work:
            steps = with_tools(steps, replace(part, verb=verb), procs, lex)
        out.extend(steps)
    return _dedupe(out)[:MAX_STEPS + MAX_TOOLS + 1]


def _carried(obj: str, lex: Lexicon) -> bool:
    return bool(obj) and not lex.is_place(obj) and lex.noun_category.get(obj) not in ("furniture", "appliances", "storage")


def _each(part: GoalPart, proc: Procedure | None, objects: list[str], lex: Lexicon) -> list[dict[str, Any]]:
    """One fetch and one action per object of a part that names several ("set the table with the
    plate, the bowl and the cutlery"): the action as the procedure says it, at the goal's place."""
    say = next((s.say for s in proc.steps if s.verb == part.verb), None) if proc else None
    say = say or _say(part.verb or "put")
    out = []
    for o in objects:
        name = part.words.get(o, display(o))
        ev = list(proc.evidence[:2]) if proc else []
        out.append({"verb_class": "take", "say": "pick up", "noun": o, "name": name, "place": "", "evidence": [],
                    "source": "precondition", "transferred_from": None, "fetch": True})
        out.append({"verb_class": part.verb or "put", "say": say, "noun": o, "name": name, "place": part.place,
                    "evidence": ev, "source": proc.kind if proc else "goal", "transferred_from": None,
                    "note": None if proc else "no remembered procedure for this action"})
    return out


def with_tools(steps: list[dict[str, Any]], part: GoalPart, procs: list[Procedure], lex: Lexicon) -> list[dict[str, Any]]:
    """Which tool: the utensils, cutlery and cookware the person handles in the remembered
    procedures that do the part's action (in at least two of them), taken up before the first step
    that does it when the plan does not already mention them."""
    if not part.verb:
        return steps
    counts: dict[str, list[str]] = {}
    acted_on: dict[str, int] = {}
    for p in procs:
        if part.verb not in [s.verb for s in p.steps]:
            continue
        targets = {s.noun for s in p.steps if s.verb == part.verb}
        for noun in targets:
            acted_on[noun] = acted_on.get(noun, 0) + 1
        for noun in {s.noun for s in p.steps if s.noun} - targets:
            if lex.noun_category.get(noun) in TOOL_CATEGORIES and noun not in part.objects:
                counts.setdefault(noun, []).append(p.source_id)
    have = {s["noun"] for s in steps}
    # used around the action more often than it is itself what the action is done to
    tools = [n for n, ids in sorted(counts.items(), key=lambda x: (-len(x[1]), x[0]))
             if len(ids) >= 2 and len(ids) > acted_on.get(n, 0) and n not in have]
    if not tools:
        return steps
    at = next((i for i, s in enumerate(steps) if s["verb_class"] == part.verb), len(steps))
    extra = [{"verb_class": "take", "say": "pick up", "noun": n, "name": display(n), "place": "",
              "evidence": counts[n][:3], "source": "tool", "transferred_from": None, "fetch": True}
             for n in tools[:MAX_TOOLS]]
    return steps[:at] + extra + steps[at:]


def _fetch(part: GoalPart, proc: Procedure | None, theme: str | None, lex: Lexicon) -> list[dict[str, Any]]:
    """A precondition step: the part's object must be at hand before it is acted on. When the
    procedure does not take the object before its first step that acts on it (and the object is
    something carried, not a fixture or a place), the plan first fetches it from where memory keeps it."""
    obj = part.objects[0] if part.objects else ""
    if not _carried(obj, lex) or _general(obj, lex):  # "vegetables": the procedure takes the person's own
        return []
    if part.verb and lex.verb_category.get(part.verb) == "retrieve":
        return []
    if proc is not None:
        target = obj if theme is None else theme
        for s in proc.steps:
            if s.noun == target:
                if lex.verb_category.get(s.verb) == "retrieve":
                    return []
                break
    return [{"verb_class": "take", "say": "pick up", "noun": obj, "name": part.words.get(obj, display(obj)), "place": "",
             "evidence": [], "source": "precondition", "transferred_from": None, "fetch": True}]


def _dedupe(steps: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for s in steps:
        if out and out[-1]["verb_class"] == s["verb_class"] and out[-1]["noun"] == s["noun"]:
            out[-1]["evidence"] = list(dict.fromkeys(out[-1]["evidence"] + s["evidence"]))
            continue
        out.append(s)
    return out


def objects_to_ground(goal: str, calls: list[dict[str, Any]], lex: Lexicon, limit: int = 6) -> list[str]:
    """The goal's objects, then the draft plan's, as words for an entity lookup."""
    names: list[str] = []
    for part in goal_parts(goal, lex):
        names += [part.words.get(o, display(o)) for o in part.objects]
    for s in compose(goal, calls, lex):
        if s["noun"]:
            names.append(display(s["noun"]))
    return list(dict.fromkeys(n for n in names if n))[:limit]


# -- grounding --------------------------------------------------------------------------------------

def groundings(calls: list[dict[str, Any]], lex: Lexicon) -> dict[str, Grounding]:
    """noun class -> the person's object of that class (name, label, location, evidence), from the
    entity tools' results; only records whose name is of the class asked about count."""
    out: dict[str, Grounding] = {}
    for c in calls:
        if c["name"] not in ("search_objects", "get_object_history", "search"):
            continue
        asked = lex.noun_classes(str(next(iter(c["arguments"].values()), "")))
        result = c.get("result")
        if not isinstance(result, ToolResult):
            continue
        for _, rec in result.records():
            found = _object_of(rec)
            if found is None:
                continue
            name, loc, label, ids = found
            classes = lex.noun_classes(name)
            for cls in classes[-1:]:  # the head noun ("pak choi leaf" is a leaf)
                if asked and cls not in asked:
                    continue
                out.setdefault(cls, Grounding(name, label, _place(loc), ids))
    return out


def _object_of(rec: Any) -> tuple[str, str, str, list[str]] | None:
    if isinstance(rec, ObjectRecord):
        vis = rec.visual_properties
        label = " ".join(x for x in (vis.get("color", ""), vis.get("material", ""), rec.name) if x)
        return rec.name, rec.spatial_info.location, label, list(rec.evidence[:2]) or [rec.entity_id]
    if isinstance(rec, VisibleObject):
        return rec.name, rec.location, rec.name, [rec.event_id]
    if isinstance(rec, GraphNode) and rec.name:
        return rec.name, rec.location or "", rec.name, [rec.id]
    return None


def prep(place: str) -> str:
    last = place.split()[-1] if place.split() else ""
    return "in" if last in _IN_PLACES else "at"


def render(verb: str, obj: str, place: str, note: str | None = None, preposition: str | None = None) -> str:
    text = f"{verb.capitalize()} the {obj}" if obj else verb.capitalize()
    if place and not (obj and place in obj):  # not "turn on the tap at the tap"
        text += f" {preposition or prep(place)} the {place}"
    return text + (f" ({note})" if note else "")


def ground(draft: list[dict[str, Any]], found: dict[str, Grounding], goal_objects: set[str],
           memory: bool, general: Any = lambda noun: False) -> list[dict[str, Any]]:
    """Structured steps: the person's object names and places; an object the goal names that memory
    has no record of is kept in the goal's words and the step says so; a place carries on from the
    step before when the procedure recorded none."""
    out = []
    place_before = ""
    holding: list[str] = []
    said: set[str] = set()
    for d in draft:
        g = found.get(d["noun"]) if d["noun"] else None
        obj = g.label if g else d["name"]
        notes = [d["note"]] if d.get("note") else []
        grounded = g is not None
        if d["noun"] and not grounded and memory and d["noun"] in goal_objects and d["noun"] not in said \
                and not general(d["noun"]):
            notes.append(f"no {d['name']} in memory")
            said.add(d["noun"])
        if not d["noun"]:
            notes.append("no object in memory for this step")
        if d.get("fetch"):
            place = (g.location if g else "") or place_before
        else:
            place = d["place"] or (g.location if g else "") or place_before
        preconditions = []
        if g and g.location:
            preconditions.append(f"{g.name} is at the {g.location}")
        if d["noun"] and d["name"] in holding and d["verb_class"] not in ("take",):
            preconditions.append(f"holding the {d['name']}")
        if d["verb_class"] == "take" and d["name"]:
            holding.append(d["name"])
        elif d["verb_class"] in ("put",) and d["name"] in holding:
            holding.remove(d["name"])
        evidence = list(dict.fromkeys(d["evidence"] + (g.evidence if g else [])))
        note = "; ".join(notes) or None
        step = {"action": d["say"], "verb": d["say"], "verb_class": d["verb_class"], "entity": obj, "object": obj,
                "location": place, "place": place, "grounded": grounded, "preconditions": preconditions,
                "evidence": evidence, "source": d["source"],
                "text": render(d["say"], obj, place, note, "from" if d.get("fetch") else d.get("preposition"))}
        if note:
            step["note"] = note
        if d.get("transferred_from"):
            step["learned_on"] = d["transferred_from"]
        out.append(step)
        place_before = place or place_before
    return out


def preferences_of(calls: list[dict[str, Any]]) -> list[PreferenceRecord]:
    return [rec for c in calls if c["name"] in ("get_preferences", "search_patterns", "search")
            and isinstance(c.get("result"), ToolResult)
            for _, rec in c["result"].records() if isinstance(rec, PreferenceRecord) and not is_task_record(rec)]
