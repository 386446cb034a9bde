"""A plan from one of the person's own tasks (the Task rows, `consolidate.tasks`): the task that does
the goal, its steps focused on what the goal is about, each (action, object) once.

**Which task.** The goal's objects are its nouns (a general one, "food" or "groceries", stands for
any object of a food category), and its product when it names one ("toast": `tasks.PRODUCTS`, the
toaster). A task fits when it handles every goal object (or the product) and, when the goal names an
action besides make / prepare / have, does it to one of them; for a product, no wash-up or put-away
fits. Of the tasks that fit, the one named after the goal comes first, then the one with the most
steps on the product, then on the goal's objects, then the shorter.

**Which steps.** The goal's key objects are its objects and product; for a task named after the
goal, also the task's main object (for a product, unless it is a food: the main object of a
toast task may be the milk poured beside it; of a tea, the jug that fills the kettle). A step is kept when it acts on a key object, puts something into
one, or (a fixture: the tap, a cupboard) opens the way to the next kept step. For a task named after
the goal, the objects a kept step works with (poured into, scooped, turned on) become key too, twice
over: the kettle and the teapot of a tea. Then each (action, object) is kept once: a cycle done three
times in memory ("take, scrub, wash, rack" per knife) is planned once. A step never moves a place
(`task_plan.acts_on_place`).
"""

from __future__ import annotations

import re
from collections import Counter
from typing import Any

from memora_graph.agent import compose
from memora_graph.agent.task_plan import FIXTURES, acts_on_place
from memora_graph.consolidate import vocab
from memora_graph.consolidate.tasks import FALLBACK_PRODUCT, FOOD, PRODUCTS
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.tasks import TaskIndex, step_kinds

INSPECTING = frozenset({"smell", "look", "check", "search", "inspect", "taste"})  # change nothing: no plan step
INTO = frozenset({"insert", "pour", "empty", "fill", "scoop", "add", "drop", "throw"})  # said "into" the place
GENERIC_GOAL_WORDS = frozenset({"make", "prepare", "cook", "do", "get", "have", "fix"})  # say what, not how
CLOSURE_ROUNDS = 2  # rounds of taking up the objects kept steps work with
_PRODUCT_WORDS = {k: g for k, g in PRODUCTS.items() if ":" not in k}


def read_tasks(memory: Any) -> TaskIndex:
    """Every one of the person's Task rows from an open memory, indexed by the object kinds they name
    (`retrieve.tasks`; a view keeps its index between plans); empty for a memory without tasks."""
    kept = getattr(memory, "tasks", None)
    if isinstance(kept, TaskIndex):
        return kept
    store, participant = getattr(memory, "store", None), getattr(memory, "participant", None)
    if store is None or participant is None:
        return TaskIndex.empty()
    return TaskIndex.read(store, participant)


def _kind(noun_class: str) -> str:
    """A lexicon class as a task's object kind ("maker:coffee" -> "coffee_maker")."""
    return "_".join(reversed(noun_class.split(":")))


def goal_objects(goal: str, lex: Lexicon) -> tuple[set[str], str | None, str | None]:
    """(the goal's object kinds, the product goal it names or None, the action it names or None)."""
    parts = compose.goal_parts(goal, lex)
    kinds = {_kind(o) for p in parts for o in p.objects}
    words = re.findall(r"[a-z]+", goal.lower())
    product = next((_PRODUCT_WORDS[w] for w in words if w in _PRODUCT_WORDS), None)
    verb = None
    if words and words[0] not in GENERIC_GOAL_WORDS:
        verb = next((p.verb for p in parts if p.verb), None)
    return kinds, product, verb


def _cat(kind: str, lex: Lexicon) -> str:
    return lex.noun_category.get(kind) or lex.noun_category.get((lex.noun_classes(kind.replace("_", " ")) or [""])[0], "")


def _general(kind: str, lex: Lexicon) -> bool:
    """A goal object that names a whole kind: "food" (groceries) any food, "vegetable" any vegetable."""
    return kind == "food" or compose._general(kind, lex)


def _covers(kind: str, have: set[str], lex: Lexicon) -> set[str]:
    """The task's objects a goal object stands for: itself, or any of its kind for a general one."""
    if kind == "food":
        return {k for k in have if _cat(k, lex) in FOOD}
    if _general(kind, lex):
        return {k for k in have if _cat(k, lex) == _cat(kind, lex)}
    return {kind} & have


def _verb_fits(verb: str, step_verb: str, lex: Lexicon) -> bool:
    return step_verb == verb or lex.same_category(verb, step_verb) or (verb == "put" and step_verb in vocab.RELEASING)


def best(goal: str, tasks: TaskIndex | list[dict[str, Any]], lex: Lexicon) -> tuple[dict[str, Any], set[str]] | None:
    """The task that does the goal and the goal's key objects in it (see the module); None when none fits.
    Only the tasks that name a kind each goal object stands for (or the product's) can fit, so only
    those are read from the index, in their order (the first of equally good ones wins, as over all)."""
    kinds, product, verb = goal_objects(goal, lex)
    product_kinds = {k for k, g in PRODUCTS.items() if g == product} if product else set()
    if any(_cat(k, lex) == "drinks" for k in product_kinds) and product != FALLBACK_PRODUCT:
        product_kinds |= {k for k, g in PRODUCTS.items() if g == FALLBACK_PRODUCT}   # a drink boils water
    if not kinds and not product_kinds:
        return None
    index = tasks if isinstance(tasks, TaskIndex) else TaskIndex.of(tasks)
    covers = {k: _covers(k, index.kinds(), lex) for k in kinds}  # a task's key objects: these & what it names
    fitting = {v for v in index.verbs() if _verb_fits(verb, v, lex)} if verb else None
    on = set().union(*covers.values()) | product_kinds
    named_by: dict[str, bool] = {}  # task goals repeat ("wash up cup"): each read once
    top = None
    for i, goal_said, family, on_key, made, verb_said, n_steps in index.step_counts(
            _candidates(index, kinds, product_kinds, covers), on, product_kinds, fitting):
        if product and family in ("cleanup", "store"):
            continue  # a wash-up or a put-away makes nothing (consolidate.tasks names them so too)
        if not verb_said:
            continue
        if goal_said not in named_by:
            named_by[goal_said] = _named(goal_said, kinds, product, verb, lex)
        score = (named_by[goal_said], made, on_key, -n_steps)
        if top is None or score > top[0]:  # the first of equally good ones
            top = (score, i)
    if top is None:
        return None
    (named, *_), i = top
    t, have = index.task(i), index.task_kinds(i)
    key = set().union(*(covers[k] & have for k in kinds)) | (product_kinds & have)
    if named:  # the task is the goal: its main object and what its work is done with too
        main = t.get("main_object") or ""
        side = product and (main in product_kinds or _cat(main, lex) in FOOD)  # milk poured beside the toast
        key = _closure(t, key | ({main} if main and not side else set()))
    return t, key


def _candidates(index: TaskIndex, kinds: set[str], product_kinds: set[str], covers: dict[str, set[str]]) -> set[int]:
    """The tasks that fit the goal's objects (`best`): for each goal object, those naming a kind it
    stands for (`covers`) or, for a goal object other than the product, the product; with no goal
    object, those naming the product. (A task's steps on them are counted after.)"""
    with_product = index.having(product_kinds)
    out: set[int] | None = None
    for k in kinds:
        fit = index.having(covers[k])
        if k not in product_kinds:
            fit |= with_product
        out = fit if out is None else out & fit
    return with_product if out is None else out


def _named(task_goal: str, kinds: set[str], product: str | None, verb: str | None, lex: Lexicon) -> bool:
    """The task is named after the goal: its product, or its words say the goal's action and objects."""
    if product:
        return task_goal == product
    said = lex.parse(task_goal)
    nouns = {_kind(n) for c in said for n in c.nouns}
    verbs = {c.verb for c in said if c.verb}
    return bool(kinds) and kinds <= nouns and (not verb or any(_verb_fits(verb, v, lex) for v in verbs))


def _closure(task: dict[str, Any], key: set[str]) -> set[str]:
    key = set(key)
    for _ in range(CLOSURE_ROUNDS):
        more = set()
        for s in task["steps"]:
            kinds = step_kinds(s)
            if kinds & key and (s["verb"] not in vocab.FILLER or s.get("place") in key):
                more |= {k for k in kinds if k not in vocab.STORAGE_KINDS and not k.endswith("_area")}
        key |= more
    return key


def focus(task: dict[str, Any], key: set[str], lex: Lexicon) -> list[dict[str, Any]]:
    """The task's steps about the key objects (see the module), without inspecting (smell, check)
    or moving a thing aside (taken and put straight back down, nothing done to it; put down and
    taken straight back up: the take alone), each (action, object, where it is put) once, no place
    moved."""
    steps = [s for s in task["steps"] if s["verb"] not in INSPECTING]
    on_key = [bool(step_kinds(s) & key) for s in steps]
    keep = list(on_key)
    for i in range(len(steps) - 1):  # a fixture worked just before a step on a key object opens the way to it
        if not keep[i] and on_key[i + 1] and _fixture(steps[i]["noun"], lex):
            keep[i] = True
    kept = [s for s, k in zip(steps, keep) if k and not acts_on_place(s["verb"], s.get("noun") or "", lex)]
    aside = set()
    for i in range(len(kept) - 1):
        a, b = kept[i], kept[i + 1]
        if a["verb"] in vocab.TAKING and b["verb"] == "put" and a["noun"] == b["noun"] and _area(b):
            aside |= {i, i + 1}
        elif a["verb"] == "put" and b["verb"] in vocab.TAKING and a["noun"] == b["noun"] and _area(a):
            aside.add(i)  # put down and taken straight back: still in hand (no plan puts down what it never took)
    out, seen = [], set()
    for i, s in enumerate(kept):
        k = (s["verb"], s.get("noun") or "", "" if _area(s) else s.get("place") or "")
        if i in aside or k in seen:
            continue
        seen.add(k)
        out.append(s)
    return out


def _area(step: dict[str, Any]) -> bool:
    """The step happens at an area (no object it is put in or on)."""
    place = step.get("place") or ""
    return not place or place.endswith((" area", " general")) or place in ("top", "worktop", "counter")


def _fixture(kind: str, lex: Lexicon) -> bool:
    return kind in FIXTURES or lex.noun_category.get(kind) in ("furniture", "storage")


def draft(task: dict[str, Any], key: set[str], lex: Lexicon) -> list[dict[str, Any]]:
    """The focused steps as compose's draft steps (before grounding)."""
    out = []
    ev = [task["id"], *(task.get("segments") or [])[:2]]
    for s in focus(task, key, lex):
        noun = s.get("noun") or ""
        cls = (lex.noun_classes(noun.replace("_", " ")) or [noun])[0] if noun else ""
        dest = s.get("place") or ""
        place = compose.display(dest) if dest else ""
        seg = [s["segment"]] if s.get("segment") else []
        into = not _area(s) and s["verb"] in INTO  # "pour the water into the kettle", not "at the kettle"
        out.append({"verb_class": lex.verb(s["verb"]) or s["verb"], "say": compose._say(s["verb"]), "noun": cls,
                    "name": noun.replace("_", " "), "place": place, "preposition": "into" if into else None,
                    "evidence": list(dict.fromkeys(ev + seg)), "source": "task", "transferred_from": None})
    return out


def summary(goal: str, tasks: TaskIndex | list[dict[str, Any]], lex: Lexicon) -> dict[str, Any] | None:
    """Which task a plan for the goal starts from and how much of it is kept (for reports, tests)."""
    hit = best(goal, tasks, lex)
    if hit is None:
        return None
    t, key = hit
    kept = focus(t, key, lex)
    return {"task": t["id"], "goal": t["goal"], "video": t["video"], "steps": len(t["steps"]), "kept": len(kept),
            "objects": [k for k, _ in Counter(s.get("noun") for s in kept).most_common()]}
