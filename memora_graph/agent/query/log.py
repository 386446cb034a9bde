"""The activity log: every narrated step of a person's memory as EPIC classes, in (video, time) order.

The steps are the columns kept with the tool stores (`MemoryView.steps`, retrieve/steps.py: every
segment's narrated steps, persisted, grown as moments are remembered); each distinct wording is
read once per view at class level (`_step_classes`): the step's action, its object, every class it
names and where it went (a narrated destination of the furniture, storage, appliance, container,
cookware, crockery, rubbish or utensil kind). The typed query (`query.answer`) is answered over
it (`StepLog`, query/steplog.py: filters once per wording, runs by array comparison).
"""

from __future__ import annotations

from memora_graph.agent.query import wordings
from memora_graph.agent.query.lexical import fix_keys, noun_classes
from memora_graph.agent.query.steplog import LogStep, StepLog, Steps
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.steps import StepRows

__all__ = ["LogStep", "StepLog", "Steps", "action_log", "action_text", "clock", "noun_words", "step_log"]

# EPIC noun categories of where things are put or taken from (a narration's second object)
PLACE_CATEGORIES = frozenset({"furniture", "storage", "appliances", "containers", "cookware", "crockery", "rubbish",
                              "utensils"})

# -- the activity log ---------------------------------------------------------------------------------

def noun_words(noun: str) -> str:
    parts = [p for p in noun.replace("_", " ").split(":") if p]
    return " ".join(parts[1:] + parts[:1]) if parts else noun


def _place_of(objects: list[str], nouns: list[str], lex: Lexicon, said: list[str | None] = ()) -> str | None:
    """Where a step's object went (or came from): the place a preposition introduces ("put can of
    tomatoes in cupboard" -> cupboard), else the first place-like class named after the object."""
    after = nouns[next((i for i, n in enumerate(nouns) if n in objects), -1) + 1:] if objects else nouns
    for n in [*said, *after]:
        if n and n not in objects and lex.noun_category.get(n, "") in PLACE_CATEGORIES:
            return n
    return None


def _step_classes(narration: str, obj: str, action: str, lex: Lexicon) -> tuple:
    """One narrated step's classes: (verb, objects, nouns, place). A function of its words alone."""
    objects = noun_classes(lex, obj.replace("_", " ").replace(":", " ")) if obj else []
    clauses = lex.parse(narration) if narration else []
    nouns = list(objects)
    said = []
    for c in clauses:
        nouns += [n for n in fix_keys(lex, narration, c.nouns) if n not in nouns]
        if c.place:
            said += fix_keys(lex, narration, [c.place])
    if not objects and nouns:
        objects = nouns[:1]
    verb = lex.verb(action) or next((c.verb for c in clauses if c.verb), None)
    return verb, tuple(dict.fromkeys(objects)), tuple(nouns), _place_of(objects, nouns, lex, said)


def action_log(view, lex: Lexicon) -> StepLog:
    """Every narrated step in the person's memory as classes, in (video, time) order
    (query/steplog.py): the steps are the columns kept with the tool stores (`view.steps`,
    retrieve/steps.py, with the segments remembered since in their place); each distinct step
    wording's classes are computed once per view (a person's narrations repeat: 1,151,204 steps
    in 31,977 wordings at 1,000 h), or read from those saved with the persisted stores
    (query/wordings.py)."""
    rows = view.steps
    cached = view.__dict__.get("_open_action_log")
    if cached is not None and cached.rows is rows:
        return cached
    wordings.seed(view, lex)  # the wordings' classes a process before saved (query/wordings.py)
    log = step_log(rows, lex, view.__dict__.setdefault(wordings.LOG_WORDS, {}), cached)
    view.__dict__["_open_action_log"] = log
    return log


def step_log(rows: StepRows, lex: Lexicon, seen: dict | None = None, grown_from: StepLog | None = None) -> StepLog:
    """The log of `rows` with each wording's classes (`_step_classes`), kept in `seen` by wording
    across calls; `grown_from`: the log of the same rows before segments were added (its
    wordings' classes are reused when they are the first of these)."""
    seen = {} if seen is None else seen
    n = len(grown_from.classes) if grown_from is not None else 0
    if n and grown_from.rows.words[:n] != rows.words[:n]:
        grown_from, n = None, 0
    classes = list(grown_from.classes) if n else []
    for narration, obj, action, _ in rows.words[n:]:
        key = (narration, obj, action)
        c = seen.get(key)
        if c is None:
            c = seen[key] = _step_classes(narration, obj, action, lex)
        classes.append(c)
    return StepLog(rows, classes, grown_from if n else None)


def clock(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    return f"{m:02d}:{s:02d}" if m < 60 else f"{m // 60}:{m % 60:02d}:{s:02d}"


def action_text(verb: str | None, noun: str | None) -> str:
    v = (verb or "").replace("-", " ")
    return f"{v} {noun_words(noun)}".strip() if noun else v


