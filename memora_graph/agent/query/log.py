"""The activity log: every narrated step of a person's memory as EPIC classes, in (video, time) order.

Read once per open view from `queries/_open_action_log.cypher` (each segment's narrated steps), at
class level: each step's action, its object, every class it names and where it went (a narrated
destination of the furniture, storage, appliance, container, cookware, crockery, rubbish or
utensil kind). The typed query (`query.answer`) is answered over it.
"""

from __future__ import annotations

import bisect
import json
from dataclasses import dataclass

from memora_graph.agent.query.lexical import fix_keys, noun_classes
from memora_graph.perceive.lexicon import Lexicon

# EPIC noun categories of where things are put or taken from (a narration's second object)
PLACE_CATEGORIES = frozenset({"furniture", "storage", "appliances", "containers", "cookware", "crockery", "rubbish",
                              "utensils"})

# -- the activity log ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class LogStep:
    video: str
    t: float
    segment: str
    verb: str | None
    objects: tuple[str, ...]  # the step's own object classes
    nouns: tuple[str, ...]  # every class the narration names
    place: str | None  # where it went / came from
    text: str


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


def _segment_steps(seg: dict, lex: Lexicon, seen: dict | None = None) -> list[LogStep]:
    """The narrated steps of one activity record (id, video, t_start, action_breakdown) as classes.
    `seen` keeps each distinct step wording's classes across calls: a person's narrations repeat
    (115,079 steps in 36,003 segments at 100 h), and parsing each again was nearly all of the
    first `ask`'s time (5.9 CPU-s at 100 h)."""
    seen = {} if seen is None else seen
    out: list[LogStep] = []
    try:
        steps = json.loads(seg["action_breakdown"] or "[]")
    except (TypeError, ValueError):
        steps = []
    t0 = float(seg["t_start"] or 0.0)
    for s in steps:
        narration = str(s.get("narration") or "")
        obj = str(s.get("object") or "")
        action = str(s.get("action") or "")
        key = (narration, obj, action)
        classes = seen.get(key)
        if classes is None:
            classes = seen[key] = _step_classes(narration, obj, action, lex)
        try:
            t = t0 + float(s.get("timestamp") or 0.0)
        except (TypeError, ValueError):
            t = t0
        out.append(LogStep(seg["video"], t, seg["id"], *classes, narration or f"{s.get('action', '')} {obj}".strip()))
    return out


def action_log(view, lex: Lexicon) -> list[LogStep]:
    """Every narrated step in the person's memory as classes, in (video, time) order; read once
    per open view. A server's reader notes the segments remembered since
    (`view._open_log_pending`, MemoryView.absorb): their steps are put in their place (after
    the steps of equal video and time, as the stable sort of a whole read puts a later turn's)."""
    cached = view.__dict__.get("_open_action_log")
    if cached is not None:
        pending = view.__dict__.pop("_open_log_pending", None)
        if pending:
            for seg in view.by_id("_tool_segment", pending):
                for step in _segment_steps(seg, lex, view.__dict__.setdefault("_open_log_words", {})):
                    bisect.insort_right(cached, step, key=lambda s: (s.video, s.t))
                    added = view.__dict__.get("_open_log_added")
                    if added is not None:  # the vocabulary takes the new steps in (query.vocabulary)
                        added.append(step)
        return cached
    view.__dict__.pop("_open_log_pending", None)
    out: list[LogStep] = []
    seen = view.__dict__["_open_log_words"] = {}
    for seg in view.fetch("_open_action_log"):
        out += _segment_steps(seg, lex, seen)
    out.sort(key=lambda s: (s.video, s.t))
    view.__dict__["_open_action_log"] = out
    return out


def action_runs(log: list[LogStep]) -> list[list[LogStep]]:
    """Consecutive steps of one video with the same action, collapsed (a run is one event)."""
    runs: list[list[LogStep]] = []
    for s in log:
        key = (s.video, s.verb, s.objects[:1])
        if runs and (runs[-1][0].video, runs[-1][0].verb, runs[-1][0].objects[:1]) == key:
            runs[-1].append(s)
        else:
            runs.append([s])
    return runs


def clock(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    return f"{m:02d}:{s:02d}" if m < 60 else f"{m // 60}:{m % 60:02d}:{s:02d}"


def action_text(verb: str | None, noun: str | None) -> str:
    v = (verb or "").replace("-", " ")
    return f"{v} {noun_words(noun)}".strip() if noun else v


