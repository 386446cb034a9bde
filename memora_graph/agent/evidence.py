"""Typed tool results -> `Event`s: every memory's records as actions and objects at the class level.

The question reader (`agent.reading`) scores options against events and never looks at which
memory they came from: MEMORA's activity records (their narrated steps), consolidated habits,
storage, tool and workflow preferences and routine steps; Flat-1D's time-stamped text records;
Graph-2D's activity, object and pattern nodes. Each event keeps the ids of the bank nodes (or
the record) behind it, so an answer can cite them.
"""

from __future__ import annotations

import math
import re

from memora_graph.agent.claims import Claim, is_task_record
from memora_graph.agent.claims import enabled as claims_enabled
from memora_graph.agent.reading import Event
from memora_graph.baselines.flat1d import FlatHit
from memora_graph.consolidate.task_records import PREFERENCE_FAMILIES
from memora_graph.baselines.graph2d import GraphNode
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.records import segment_id
from memora_graph.retrieve.results import (
    Action, ActivityRecord, ObjectHistoryResult, ObjectRecord, PreferenceRecord, RoutineRecord, ToolResult,
    VideoActivitiesResult,
)

_STAMP = re.compile(r"^\[(?P<video>[^\s\[\]]+) (?P<t>[\d.]+)(?:-[\d.]+)?s[^\]]*\]\s*")
_STEP_T = re.compile(r"^([\d.]+)")


def events_of(result: ToolResult, lex: Lexicon) -> list[Event]:
    """Every action and object a tool result holds, as events."""
    return [e for group in record_events(result, lex) for e in group]


def record_events(result: ToolResult, lex: Lexicon) -> list[list[Event]]:
    """The events of a tool result, one list per record, in the result's order."""
    out: list[list[Event]] = []
    for kind, rec in result.records():
        out.append(_record_events(kind, rec, lex))
    if isinstance(result, ObjectHistoryResult) and result.found and result.state_history:
        nouns = tuple(lex.noun_classes(result.name or "")) or ()
        for h in result.state_history:
            out.append([Event(h.video, float(h.time_seconds), lex.verb(h.action), nouns, (h.event_id, h.segment_id))])
    if isinstance(result, VideoActivitiesResult):
        for o in result.objects:
            out.append([Event(result.video, -1.0, None, tuple(object_classes(o.kind, lex) if o.kind else lex.noun_classes(o.name)),
                              (), origin="object")])
    return out


def budgeted_events(results: list[ToolResult], lex: Lexicon, budget: int | None = None) -> list[Event]:
    """The events of the records a reader limited to `budget` records reads (None: all of them):
    the calls' records taken in turn, each call's best-ranked first, as a model's context would
    hold the first K records of its tool results. The experiment of how much each memory says in
    few records (MEMORA's consolidated habits and routines against MEMORA-Episodic's episodes)."""
    groups = [record_events(r, lex) for r in results]
    if budget is None:
        return [e for g in groups for rec in g for e in rec]
    out: list[Event] = []
    taken, depth = 0, 0
    while taken < budget and any(depth < len(g) for g in groups):
        for g in groups:
            if depth < len(g) and taken < budget:
                out += g[depth]
                taken += 1
        depth += 1
    return out


def _actions(text: str, lex: Lexicon) -> list[tuple[str | None, tuple[str, ...]]]:
    """A summary line ("take plate; wash plate; put plate on rack") as its actions, in order."""
    return [(c.verb, tuple(dict.fromkeys(c.nouns))) for part in _parts(text) for c in lex.parse(part) if c.verb or c.nouns]


def _parts(text: str) -> list[str]:
    return [p.strip() for p in re.split(r"[;.]\s*|\s->\s", text) if p.strip()]


def _line_events(video: str, t0: float, text: str, ids: tuple[str, ...], lex: Lexicon, spacing: float = 1.0,
                 weight: float = 1.0, origin: str = "log") -> list[Event]:
    """A log line's actions as events (`_actions`), each with its narrated verb word."""
    out = []
    for part in _parts(text):
        for c, word in zip(lex.parse(part), lex.verb_words(part)):
            if c.verb or c.nouns:
                out.append(Event(video, t0 + len(out) * spacing, c.verb, tuple(dict.fromkeys(c.nouns)), ids, weight,
                                 origin, text=text, word=word or ""))
    return out


def _weight(count: int | None) -> float:
    """What repetition is worth: a record counted n times weighs 1 + ln n (diminishing)."""
    return 1.0 + math.log(max(1, count or 1))


def object_classes(name: str, lex: Lexicon) -> list[str]:
    """A memory's object name as noun classes: a class key as itself ("board:chopping",
    "liquid:washing"), a compound read in English order ("washing liquid"), else its words."""
    o = name.strip().lower().replace("_", " ")
    if o in lex.noun_category:
        return [o]
    parts = [p.strip() for p in o.split(":") if p.strip()]
    if len(parts) > 1:
        hit = lex.noun_classes(" ".join([*reversed(parts[1:]), parts[0]]))
        if hit:
            return hit
    return lex.noun_classes(o.replace(":", " "))


def _step_action(a: Action, lex: Lexicon) -> tuple[str | None, tuple[str, ...]]:
    nouns = [n for n in (a.noun, a.instrument, a.place) if n]
    classes = []
    for n in nouns:
        classes += object_classes(n, lex) or [n]
    return lex.verb(a.verb), tuple(dict.fromkeys(classes))


def _record_events(kind: str, rec, lex: Lexicon) -> list[Event]:
    if is_task_record(rec) and not claims_enabled():  # MEMORA_TASK_CLAIMS=off: the reader of before the task memory
        return []
    if isinstance(rec, ActivityRecord):
        return _activity_events(rec, lex)
    if isinstance(rec, ObjectRecord):
        nouns = tuple(object_classes(rec.kind, lex) or lex.noun_classes(rec.name))
        return [Event("", -1.0, None, nouns, (rec.entity_id,), origin="object")]
    if isinstance(rec, PreferenceRecord):
        return _preference_events(rec, lex)
    if isinstance(rec, RoutineRecord):
        ids = (rec.routine_id, *rec.supporting_episodes[:5])
        if rec.steps:
            steps = [_step_action(s, lex) for s in rec.steps]
        else:
            steps = [a for s in rec.canonical_steps for a in _actions(s.action, lex)]
        weight = _weight(rec.count)
        return [Event(f"routine:{rec.routine_id}", float(i), v, ns, ids, weight, text=rec.text())
                for i, (v, ns) in enumerate(steps)]
    if isinstance(rec, FlatHit):
        m = _STAMP.match(rec.text())
        video, t = (m["video"], float(m["t"])) if m else (rec.video, rec.time)
        body = rec.text()[m.end():] if m else rec.text()
        ids = (f"{video}@{t:.1f}s",)
        if rec.kind == "activity":
            return _line_events(video, t, body, ids, lex)
        nouns = tuple(lex.noun_classes(body.split(":")[0]))
        return [Event(video, -1.0, None, nouns, ids, origin="object")] if nouns else []
    if isinstance(rec, GraphNode):
        if kind in ("activities", "history", "moments") or rec.turn is not None:
            t = float(rec.time if rec.time is not None else 0.0)
            out = _line_events(rec.video or "", t, rec.text(), (rec.id,), lex)
            if rec.context is not None:
                out = _line_events(rec.video or "", t - 10, rec.context.previous, (rec.id,), lex) + out + \
                    _line_events(rec.video or "", t + 10, rec.context.next, (rec.id,), lex)
            return out
        if kind == "objects" or rec.name:
            nouns = tuple(lex.noun_classes(rec.name or rec.text().split(":")[0]))
            return [Event(rec.video or "", -1.0, None, nouns, (rec.id,), origin="object")] if nouns else []
        if kind == "patterns":
            goal, _, steps = rec.text().partition(":")
            return [Event(f"pattern:{rec.id}", float(i), v, ns, (rec.id,)) for i, (v, ns) in
                    enumerate(_actions(steps.split("(objects:")[0], lex))]
        return []
    return []


def _activity_events(rec: ActivityRecord, lex: Lexicon) -> list[Event]:
    video, t0 = rec.source_video, float(rec.time.start)
    out = []
    for s in rec.action_breakdown:
        m = _STEP_T.match(s.t)
        t = t0 + (float(m.group(1)) if m else 0.0)
        nouns = object_classes(s.object, lex) if s.object else []
        if s.narration:
            nouns += [n for c in lex.parse(s.narration) for n in c.nouns if n not in nouns]
        verb = lex.verb(s.action) or next((c.verb for c in lex.parse(s.narration) if c.verb), None)
        word = next((w for w in lex.verb_words(s.narration or "") if w), "") if verb else ""
        out.append(Event(video, t, verb, tuple(dict.fromkeys(nouns)), (rec.segment_id,), text=s.narration, word=word))
    if not out and rec.summary:
        out = _line_events(video, t0, rec.summary, (rec.segment_id,), lex)
    turn = rec.turn_id
    if rec.previous_action:
        out = _line_events(video, t0 - 10, rec.previous_action, (segment_id(video, turn - 1),), lex) + out
    if rec.next_action:
        out += _line_events(video, float(rec.time.end), rec.next_action, (segment_id(video, turn + 1),), lex)
    return out


def _preference_events(p: PreferenceRecord, lex: Lexicon) -> list[Event]:
    ids = (p.preference_id, *p.supporting_episodes[:5])
    weight = _weight(p.count)
    if p.subtype == "habit" and p.trigger_step is not None and p.next_step is not None:
        v, ns = _step_action(p.trigger_step, lex)
        nv, nns = _step_action(p.next_step, lex)
        return [Event("", -1.0, v, ns, ids, weight, "habit", ((nv, nns),), text=p.preference)]
    if p.subtype == "habit" and p.trigger and p.next_action:
        trig, nxt = _actions(p.trigger, lex), _actions(p.next_action, lex)
        if trig and nxt:
            return [Event("", -1.0, trig[0][0], trig[0][1], ids, weight, "habit", tuple(nxt[:1]), text=p.preference)]
    if p.subtype == "storage" and p.object and p.preferred_location:
        nouns = object_classes(p.object, lex) + lex.noun_classes(p.preferred_location)
        verb = None if p.context == "during_use" else "put"  # "usually uses X at Y" is where it is used, not kept
        return [Event("", -1.0, verb, tuple(dict.fromkeys(nouns)), ids, weight, "storage", text=p.preference)]
    if p.subtype == "workflow" and p.use:
        verb, _, where = p.use.partition(" @ ")
        nouns = [n for o in p.objects for n in object_classes(o, lex)] + lex.noun_classes(where)
        after = _actions(p.then or "", lex)
        return [Event("", -1.0, lex.verb(verb.strip()), tuple(dict.fromkeys(nouns)), ids, weight, "storage",
                      tuple(after[:1]), text=p.preference)]
    if p.subtype in PREFERENCE_FAMILIES and p.actions:
        return _pattern_events(p, ids, weight, lex)
    if p.actions:
        return [Event("", -1.0, *_step_action(a, lex), ids, weight, "tool", text=p.preference) for a in p.actions]
    return []


def _pattern_events(p: PreferenceRecord, ids: tuple[str, ...], weight: float, lex: Lexicon) -> list[Event]:
    """A task-pattern record: its actions as consolidated events, the first carrying the record
    as a `Claim` the reader checks options against (`agent.claims`). Their origin, "pattern", keeps
    them out of the reader's context windows: they speak only through the claims they make."""
    steps = [_step_action(a, lex) for a in p.actions]
    nouns = [n for o in p.objects for n in object_classes(o, lex)]
    way = p.context
    if p.subtype == "carrier":
        way = "with" if any(a.instrument for a in p.actions) else "directly"
    share = min(1.0, p.count / p.total) if p.total else p.confidence
    claim = Claim(p.subtype, way, tuple(v for v, _ in steps), tuple(dict.fromkeys(nouns)), float(share), ids)
    return [Event("", -1.0, v, ns, ids, weight, "pattern", text=p.preference, claim=claim if i == 0 else None)
            for i, (v, ns) in enumerate(steps)]
