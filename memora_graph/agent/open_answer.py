"""Open questions answered in the type they ask for, from one person's typed memory.

    from memora_graph.agent.open_answer import answer_open
    with MemoryView.open("banks/epic", "P01") as view:
        a = answer_open(view, "P01", "Where did P01 last put the chopping board?")
        a.kind, a.place, a.evidence, a.confidence

`open_parse.parse_open` says what is asked; this module reads it from the stores:

- the activity log (every segment's narrated steps, kept as columns with the tool stores:
  retrieve/steps.py, agent/steplog.py), read at EPIC class level: each step's action, its object, and where it went (a narrated destination
  of the furniture, storage, appliance, container, cookware, crockery, rubbish or utensil kind);
- the consolidated stores: storage preferences (where something is usually kept), habits (what
  follows a trigger) and routines (the ordered steps of a goal), used where they speak to the
  question, with the episodes behind them;
- the state history of a video (`_tool_video_events`) for the state of an object at a time.

Every answer is an `OpenAnswer`: the kind, the typed value (a place, a video and time, a number
with the records counted, yes/no, next actions with their share, routine steps, states, a log),
the evidence ids (segments, state events, preferences, routines), a confidence (a probability
from `open_calibration`), and for "not in memory" which reason: general knowledge, or a subject
absent from this person's memory.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from typing import Literal

from pydantic import BaseModel, Field

from memora_graph.agent.open_parse import OpenQuestion, fix_keys, noun_classes, parse_open
from memora_graph.agent.steplog import LogStep, StepLog, Steps
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.steps import StepRows

NOT_IN_MEMORY = "not in memory"
# EPIC noun categories of where things are put or taken from (a narration's second object)
PLACE_CATEGORIES = frozenset({"furniture", "storage", "appliances", "containers", "cookware", "crockery", "rubbish",
                              "utensils"})
PUT_VERBS = frozenset({"put", "insert", "throw", "drop"})
TAKE_VERBS = frozenset({"take", "remove"})
MAX_ACTIONS = 3
MAX_EVIDENCE = 20


# -- the typed result ---------------------------------------------------------------------------------

class PlaceValue(BaseModel):
    place: str = Field(description="EPIC noun class of the place (e.g. 'drawer', 'board:chopping').")
    name: str = Field(description="The place in words.")
    video: str | None = Field(None, description="Video of the observation (last / first put).")
    time_seconds: float | None = Field(None, description="Seconds into that video.")
    count: int = Field(0, description="Observations of the object put (or taken) there.")
    share: float | None = Field(None, description="Share of all the object's placements that went there.")


class MomentValue(BaseModel):
    video: str
    time_seconds: float
    clock: str = Field(description="The time as MM:SS into the video.")


class ActionShare(BaseModel):
    verb: str = Field(description="EPIC verb class.")
    noun: str = Field(description="EPIC noun class ('' when none).")
    text: str
    count: int
    share: float = Field(description="Share of the observed cases.")


class RoutineStep(BaseModel):
    order: int
    verb: str
    noun: str
    text: str


class ObjectStateEvent(BaseModel):
    object: str
    state: str
    location: str
    video: str
    time_seconds: float
    event_id: str


class LogLine(BaseModel):
    video: str
    time_seconds: float
    text: str
    segment_id: str


class OpenAnswer(BaseModel):
    """An open question's answer in the type asked, with its evidence and confidence."""

    question: str
    participant: str
    asked: str = Field(description="What the question asks for: " + ", ".join(
        ("count", "time", "place", "yesno", "state", "activity", "next", "routine", "actions", "general")))
    kind: str = Field(description="The answer's type: the asked kind, or 'not_in_memory'.")
    answer: str = Field(description="The answer in words.")
    in_memory: bool
    subject: dict[str, list[str]] = Field(default_factory=dict, description="The verb and noun classes asked about.")
    place: PlaceValue | None = None
    moment: MomentValue | None = None
    count: int | None = None
    yes: bool | None = None
    actions: list[ActionShare] = Field(default_factory=list)
    steps: list[RoutineStep] = Field(default_factory=list)
    states: list[ObjectStateEvent] = Field(default_factory=list)
    log: list[LogLine] = Field(default_factory=list)
    reason: Literal["general_knowledge", "absent_subject"] | None = Field(
        None, description="Why not in memory: general knowledge, or a subject absent from this person's memory.")
    detail: str = Field("", description="What the answer rests on, in words.")
    evidence: list[str] = Field(default_factory=list, description="Ids of the records behind the answer.")
    records: list[LogLine] = Field(default_factory=list, description="The narrated steps behind the answer (for a "
                                                                    "count, the records counted; at most 20).")
    support: int = Field(0, description="How many records support the answer.")
    confidence: float = Field(0.0, description="Probability that the answer is right (open_calibration.json).")
    features: dict[str, float] = Field(default_factory=dict, description="The evidence features the confidence reads.")


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
    (agent/steplog.py): the steps are the columns kept with the tool stores (`view.steps`,
    retrieve/steps.py, with the segments remembered since in their place); each distinct step
    wording's classes are computed once per view (a person's narrations repeat: 1,151,204 steps
    in 31,977 wordings at 1,000 h)."""
    rows = view.steps
    cached = view.__dict__.get("_open_action_log")
    if cached is not None and cached.rows is rows:
        return cached
    log = step_log(rows, lex, view.__dict__.setdefault("_open_log_words", {}), cached)
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


# -- matching ------------------------------------------------------------------------------------------

def _subject(q: OpenQuestion) -> list[str]:
    """The objects asked about (a place the question names is context, not subject)."""
    return [n for n in q.nouns if n != q.place] or list(q.nouns)


GENERIC_VERBS = frozenset({"use"})  # "does P use the kettle": any action with it


def _verb_ok(want: str | None, have: str | None, loose: bool) -> bool:
    if want is None or want in GENERIC_VERBS:
        return True
    if have == want:
        return True
    return loose and have is not None and want in PUT_VERBS and have in PUT_VERBS


def _matches(s: LogStep, q: OpenQuestion, loose: bool = False) -> bool:
    subject = _subject(q)
    if not _verb_ok(q.verb, s.verb, loose):
        return False
    generic = q.verb is None or q.verb in GENERIC_VERBS
    if subject and not (set(subject[:1]) & set(s.objects) or (generic and set(subject[:1]) & set(s.nouns))):
        return False
    if q.place and q.place in subject[1:] and q.place not in s.nouns:
        return False
    if q.place and q.place not in subject and q.place not in s.nouns:
        return False
    return True


def _records(log: StepLog, q: OpenQuestion, ids: list[str]) -> list[LogLine]:
    """The steps of the cited segments that the question is about (else the segment's steps)."""
    steps = list(log.of_segments(ids))
    about = [s for s in steps if _matches(s, q, loose=True)] or [s for s in steps if set(_subject(q)) & set(s.nouns)]
    return [LogLine(video=s.video, time_seconds=round(s.t, 2), text=s.text, segment_id=s.segment)
            for s in (about or steps)][:MAX_EVIDENCE]


def _ids(steps: list[LogStep] | Steps) -> list[str]:
    if isinstance(steps, Steps):
        return steps.segment_ids(MAX_EVIDENCE)
    return list(dict.fromkeys(s.segment for s in steps))[:MAX_EVIDENCE]


def _videos(steps: Steps) -> list[str]:
    return steps.videos()


# -- answering -----------------------------------------------------------------------------------------

def answer_open(view, participant: str, question: str, lex: Lexicon | None = None) -> OpenAnswer:
    """Answer an open question from `view` (a `MemoryView` of `participant`) in the type asked."""
    lex = lex or Lexicon.load()
    q = parse_open(question, lex, participant)
    base = {"question": question, "participant": participant, "asked": q.kind,
            "subject": {"verbs": list(q.verbs), "nouns": list(q.nouns)}}
    log = action_log(view, lex)
    answer = _not_in_memory(view, participant, q, log, base) or _ANSWER[q.kind](view, q, log, lex, base)
    if answer.in_memory and not answer.records and answer.evidence:
        answer.records = _records(log, q, answer.evidence)
    from memora_graph.agent.open_calibration import calibrate

    answer.confidence = calibrate(answer)
    return answer


def _nim(base: dict, reason: str, detail: str, **features) -> OpenAnswer:
    return OpenAnswer(**base, kind="not_in_memory", answer=NOT_IN_MEMORY, in_memory=False, reason=reason, detail=detail,
                      features={"nim": 1.0, **features})


def _not_in_memory(view, participant: str, q: OpenQuestion, log: StepLog, base: dict) -> OpenAnswer | None:
    if q.kind == "general":
        return _nim(base, "general_knowledge", "the question asks about the world, not about what this person did")
    others = [p for p in q.persons if p != participant]
    if others and participant not in q.persons:
        return _nim(base, "absent_subject", f"the question is about {', '.join(others)}; this is {participant}'s memory")
    missing = [v for v in q.videos if v not in view.videos]
    if missing:
        return _nim(base, "absent_subject", f"no video {', '.join(missing)} in {participant}'s memory")
    if q.kind in ("activity", "state") and q.videos:
        return None
    nouns, verbs = log.nouns, log.verbs
    subject = _subject(q)
    if not subject and (not q.verbs or set(q.verbs) <= GENERIC_VERBS):
        what = ", ".join(q.unknown) if q.unknown else "what the question names"
        return _nim(base, "absent_subject", f"{what}: no such action or object in {participant}'s memory")
    if subject and subject[0] not in nouns:
        return _nim(base, "absent_subject", f"no {noun_words(subject[0])} in {participant}'s memory")
    if not subject and q.verb and q.verb not in verbs:
        return _nim(base, "absent_subject", f"{participant} is never seen to {q.verb}")
    if q.kind == "yesno" and q.unknown and not subject:
        return _nim(base, "absent_subject", f"no {', '.join(q.unknown)} in {participant}'s memory")
    return None


def _features(support: int, share: float = 1.0, margin: float = 1.0, fallback: bool = False, exact: bool = True) -> dict:
    return {"log_support": math.log1p(max(0, support)), "share": float(share), "margin": float(margin),
            "fallback": 1.0 if fallback else 0.0, "exact": 1.0 if exact else 0.0}


def _place(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    subject = _subject(q)
    noun = subject[0] if subject else None
    verbs = TAKE_VERBS if q.source else PUT_VERBS
    cands = log.where(lambda s: s.place and noun in s.objects and s.verb in verbs and s.place != noun)
    what = noun_words(noun) if noun else "it"
    if cands:
        if q.order in ("last", "first"):
            s = cands[-1] if q.order == "last" else cands[0]
            total = Counter(c.place for c in cands)
            pv = PlaceValue(place=s.place, name=noun_words(s.place), video=s.video, time_seconds=round(s.t, 2),
                            count=total[s.place], share=round(total[s.place] / len(cands), 3))
            word = "last" if q.order == "last" else "first"
            verb = "took" if q.source else "put"
            text = f"{pv.name} ({word} {verb} there in {s.video} at {clock(s.t)})"
            return OpenAnswer(**base, kind="place", answer=text, in_memory=True, place=pv, evidence=[s.segment],
                              support=len(cands), detail=f"{len(cands)} placements of the {what} in memory",
                              features=_features(len(cands), 1.0, 1.0))
        counts = Counter(c.place for c in cands)
        (best, n), *rest = counts.most_common()
        share = n / len(cands)
        margin = share - (rest[0][1] / len(cands) if rest else 0.0)
        last = [c for c in cands if c.place == best][-1]
        pv = PlaceValue(place=best, name=noun_words(best), video=last.video, time_seconds=round(last.t, 2), count=n,
                        share=round(share, 3))
        prefs = _storage_prefs(view, noun, lex)
        text = f"{pv.name} ({n} of {len(cands)} times, {share:.0%}; last in {last.video} at {clock(last.t)})"
        return OpenAnswer(**base, kind="place", answer=text, in_memory=True, place=pv,
                          evidence=_ids([c for c in cands if c.place == best]) + [p["id"] for p in prefs][:3],
                          support=n, detail=f"where the {what} was {'taken from' if q.source else 'put'}, by count",
                          features=_features(n, share, margin, exact=False))
    prefs = _storage_prefs(view, noun, lex)
    if prefs:
        p = prefs[0]
        place = (lex.noun_classes(str(p["detail"].get("preferred_location", ""))) or [""])[0]
        pv = PlaceValue(place=place or str(p["detail"].get("preferred_location", "")),
                        name=str(p["detail"].get("preferred_location", "")), count=int(p.get("count") or 0))
        return OpenAnswer(**base, kind="place", answer=f"{pv.name} ({p['statement']})", in_memory=True, place=pv,
                          evidence=[p["id"], *p.get("supporting_episodes", [])[:5]], support=pv.count,
                          detail="a consolidated storage preference", features=_features(pv.count, 1.0, 1.0, True, False))
    if not q.source:  # where it is taken from is where it is kept
        taken = log.where(lambda s: s.place and noun in s.objects and s.verb in TAKE_VERBS and s.place != noun)
        if taken:
            counts = Counter(c.place for c in taken)
            best, n = counts.most_common(1)[0]
            last = [c for c in taken if c.place == best][-1]
            pv = PlaceValue(place=best, name=noun_words(best), video=last.video, time_seconds=round(last.t, 2), count=n,
                            share=round(n / len(taken), 3))
            return OpenAnswer(**base, kind="place", answer=f"{pv.name} (taken from there {n} of {len(taken)} times)",
                              in_memory=True, place=pv, evidence=_ids([c for c in taken if c.place == best]),
                              support=n, detail=f"no placement of the {what} recorded; where it was taken from",
                              features=_features(n, n / len(taken), 0.0, True, False))
    ents = [e for e in view.entities.values() if e.get("status") == "active" and noun in
            lex.noun_classes(f"{e.get('kind', '')} {e.get('name', '')}".replace("_", " ")) and e.get("location")]
    if ents:
        e = max(ents, key=lambda e: e.get("n_observations") or 0)
        loc = str(e["location"])
        place = (lex.noun_classes(loc.replace("_", " ")) or [loc])[0]
        pv = PlaceValue(place=place, name=loc.replace("_", " "), video=e.get("last_video"),
                        time_seconds=e.get("last_seen"), count=1)
        return OpenAnswer(**base, kind="place", answer=f"{pv.name} (where the {what} was last seen, {e.get('last_video')}"
                          f" at {clock(float(e.get('last_seen') or 0))})", in_memory=True, place=pv, evidence=[e["id"]],
                          support=int(e.get("n_observations") or 0), detail="the object's last recorded location",
                          features=_features(int(e.get("n_observations") or 0), 0.5, 0.0, True, False))
    seen = log.where(lambda s: noun in s.nouns and s.place and s.place != noun)
    if seen:
        s = seen[-1] if q.order != "first" else seen[0]
        pv = PlaceValue(place=s.place, name=noun_words(s.place), video=s.video, time_seconds=round(s.t, 2), count=1)
        return OpenAnswer(**base, kind="place", answer=f"{pv.name} (seen with it in {s.video} at {clock(s.t)})",
                          in_memory=True, place=pv, evidence=[s.segment], support=len(seen),
                          detail="no placement recorded; the place it was last seen with",
                          features=_features(len(seen), 0.5, 0.0, True, False))
    return OpenAnswer(**base, kind="place", answer=f"no place recorded for the {what}", in_memory=True,
                      detail="the object is in memory but never put anywhere", features=_features(0, 0.0, 0.0, True))


def _storage_prefs(view, noun: str | None, lex: Lexicon) -> list[dict]:
    if not noun:
        return []
    out = []
    for p in view.preferences.values():
        if p.get("subtype") != "storage":
            continue
        detail = p.get("detail") or {}
        if isinstance(detail, str):
            try:
                detail = json.loads(detail)
            except ValueError:
                detail = {}
        obj = str(detail.get("object") or " ".join(p.get("objects") or []))
        if noun in lex.noun_classes(obj.replace("_", " ")):
            out.append({**p, "detail": detail})
    return sorted(out, key=lambda p: -(p.get("count") or 0))


def _time(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    hits = log.where(lambda s: _matches(s, q))
    exact = True
    if not hits:
        hits = log.where(lambda s: _matches(s, q, loose=True))
        exact = False
    if not hits:
        return _never(q, base)
    s = hits[0] if q.order == "first" else hits[-1]
    word = "first" if q.order == "first" else "last"
    videos = _videos(hits)
    m = MomentValue(video=s.video, time_seconds=round(s.t, 2), clock=clock(s.t))
    return OpenAnswer(**base, kind="time", answer=f"{s.video} at {m.clock} ({word} of {len(hits)} times, in "
                      f"{len(videos)} videos)", in_memory=True, moment=m, evidence=[s.segment], support=len(hits),
                      detail=f"{s.text} ({word} time)", features=_features(len(hits), 1.0, 1.0, exact=exact))


def _never(q: OpenQuestion, base: dict) -> OpenAnswer:
    asked = action_text(q.verb, _subject(q)[0] if _subject(q) else None)
    return OpenAnswer(**base, kind=q.kind, answer=f"never recorded: {asked}",
                      in_memory=True, yes=False if q.kind == "yesno" else None, count=0 if q.kind == "count" else None,
                      detail=f"its objects are in memory, never with this action ({asked})",
                      features=_features(0, 0.0, 0.0))


def _count(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    hits = log.where(lambda s: _matches(s, q))
    if not hits:
        return _never(q, base)
    videos = _videos(hits)
    n = len(videos) if q.unit == "videos" else len(hits)
    unit = "videos" if q.unit == "videos" else "times"
    asked = action_text(q.verb, _subject(q)[0] if _subject(q) else None)
    return OpenAnswer(**base, kind="count", answer=f"{n} {unit} ({asked}; {len(hits)} records in {len(videos)} videos)",
                      in_memory=True, count=n, evidence=_ids(hits), support=len(hits),
                      detail=f"counted {len(hits)} records of '{asked}'", features=_features(len(hits), 1.0, 1.0))


def _yesno(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    hits = log.where(lambda s: _matches(s, q, loose=True))
    if not hits:
        return _never(q, base)
    videos = _videos(hits)
    return OpenAnswer(**base, kind="yesno", answer=f"yes ({len(hits)} times in {len(videos)} videos; last in "
                      f"{hits[-1].video} at {clock(hits[-1].t)}: {hits[-1].text})", in_memory=True, yes=True,
                      evidence=_ids(hits), support=len(hits), detail=hits[-1].text, features=_features(len(hits)))


def _shares(counts: Counter, total: int) -> list[ActionShare]:
    return [ActionShare(verb=v or "", noun=n or "", text=action_text(v, n), count=c, share=round(c / total, 3))
            for (v, n), c in counts.most_common(MAX_ACTIONS)]


def _next(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    subject = _subject(q)
    counts: Counter = Counter()
    follows: dict = {}  # the first few steps of each following action
    after = log.runs_followed(lambda s: not ((q.verb and s.verb != q.verb) or (subject and subject[0] not in s.objects)))
    pairs = log._pairs()[0]
    for p, k in zip(after.tolist(), log.pair_ids(after).tolist()):
        key = pairs[k]
        counts[key] += 1
        shown = follows.setdefault(key, [])
        if len(shown) < 5:
            shown.append(log.step(p))
    ids = {key: [st.segment for st in sts] for key, sts in follows.items()}
    if not counts:
        return _never(q, base) if q.verb else _actions(view, q, log, lex, base)
    total = sum(counts.values())
    acts = _shares(counts, total)
    margin = acts[0].share - (acts[1].share if len(acts) > 1 else 0.0)
    trig = action_text(q.verb, subject[0] if subject else None)
    text = "; ".join(f"{a.text} ({a.share:.0%})" for a in acts)
    shown = [st for key, _ in counts.most_common(MAX_ACTIONS) for st in follows[key][:5]]
    records = [LogLine(video=st.video, time_seconds=round(st.t, 2), text=st.text, segment_id=st.segment) for st in shown]
    return OpenAnswer(**base, kind="next", answer=text, in_memory=True, actions=acts, records=records,
                      evidence=list(dict.fromkeys(i for a in counts.most_common(MAX_ACTIONS) for i in ids[a[0]][:5])),
                      support=acts[0].count, detail=f"what followed '{trig}' in {total} cases",
                      features=_features(acts[0].count, acts[0].share, margin, exact=False))


def _actions(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    subject = _subject(q)
    hits = log.where(lambda s: (not subject or subject[0] in s.nouns) and _verb_ok(q.verb, s.verb, True))
    if not hits:
        return _never(q, base)
    counts = log.action_counts(hits)
    acts = _shares(counts, len(hits))
    margin = acts[0].share - (acts[1].share if len(acts) > 1 else 0.0)
    return OpenAnswer(**base, kind="actions", answer="; ".join(f"{a.text} ({a.share:.0%})" for a in acts),
                      in_memory=True, actions=acts, evidence=_ids(hits), support=acts[0].count,
                      detail=f"the actions recorded with the {noun_words(subject[0]) if subject else 'subject'}",
                      features=_features(acts[0].count, acts[0].share, margin, exact=False))


def _routine(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    subject = set(_subject(q))
    best, best_score = None, 0.0
    for r in view.routines.values():
        goal = lex.parse(str(r.get("goal") or ""))
        gverbs = {c.verb for c in goal if c.verb}
        gnouns = {n for c in goal for n in c.nouns} | {n for o in r.get("key_objects") or [] for n in lex.noun_classes(o)}
        score = (1.0 if q.verb and q.verb in gverbs else 0.0) + 2.0 * len(subject & gnouns) + \
            0.01 * math.log1p(r.get("count") or 0)
        if score > best_score and (subject & gnouns or not subject):
            best, best_score = r, score
    if best is not None:
        steps = []
        for i, s in enumerate(best.get("canonical_steps") or []):
            c = next(iter(lex.parse(s)), None)
            steps.append(RoutineStep(order=i + 1, verb=(c.verb if c and c.verb else ""),
                                     noun=(c.nouns[0] if c and c.nouns else ""), text=s))
        n = int(best.get("count") or 0)
        return OpenAnswer(**base, kind="routine", answer=" -> ".join(s.text for s in steps) +
                          f" (routine '{best.get('goal')}', seen {n} times)", in_memory=True, steps=steps,
                          evidence=[best["id"], *(best.get("supporting_episodes") or [])[:5]], support=n,
                          detail=f"the consolidated routine '{best.get('goal')}'",
                          features=_features(n, float(best.get("confidence") or 0.5), 1.0, exact=False))
    # no routine: the steps that most often surround the goal action in the episodes
    windows: Counter = Counter(log.run_windows(
        lambda s: not ((q.verb and s.verb != q.verb) or (subject and not subject & set(s.objects))), 1, 2))
    if not windows:
        return _never(q, base)
    seq, n = windows.most_common(1)[0]
    steps = [RoutineStep(order=i + 1, verb=v or "", noun=o, text=action_text(v, o)) for i, (v, o) in enumerate(seq)]
    return OpenAnswer(**base, kind="routine", answer=" -> ".join(s.text for s in steps) + f" (seen {n} times)",
                      in_memory=True, steps=steps, support=n, detail="the most common sequence around it in the episodes",
                      features=_features(n, n / sum(windows.values()), 0.0, True, False))


def _state(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    video = q.videos[0] if q.videos else None
    if video is None:
        return _actions(view, q, log, lex, base)
    t = q.time if q.time is not None else float("inf")
    rows = view.fetch("_tool_video_events", video=video)
    subject = set(_subject(q))
    last: dict[str, dict] = {}
    for r in rows:
        if r["t"] <= t:
            last[r["entity"]] = r
    states = []
    for ent, r in last.items():
        info = view.entities.get(ent, {})
        classes = set(lex.noun_classes(f"{info.get('kind', '')} {info.get('name', '')}".replace("_", " ")))
        if subject and not subject & classes:
            continue
        states.append(ObjectStateEvent(object=info.get("name", ent), state=r["state"] or "", location=r["location"] or "",
                                  video=video, time_seconds=round(r["t"], 2), event_id=r["id"]))
    states.sort(key=lambda s: -s.time_seconds)
    states = states[:5]
    if not states:
        return OpenAnswer(**base, kind="state", answer=f"nothing recorded about it in {video} by then", in_memory=True,
                          features=_features(0, 0.0, 0.0))
    text = "; ".join(f"{s.object}: {s.state} at {s.location.replace('_', ' ')} (since {clock(s.time_seconds)})"
                     for s in states)
    at = f"at {clock(q.time)}" if q.time is not None else "at its end"
    return OpenAnswer(**base, kind="state", answer=text, in_memory=True, states=states,
                      evidence=[s.event_id for s in states], support=len(states), features=_features(len(states)),
                      detail=f"the state history of {video} {at}")


def _activity(view, q: OpenQuestion, log: StepLog, lex: Lexicon, base: dict) -> OpenAnswer:
    video = q.videos[0]
    steps = list(log.of_video(video))
    subject = set(_subject(q))
    if subject:
        steps = [s for s in steps if subject & set(s.nouns)] or steps
    if q.time is not None:
        near = [s for s in steps if abs(s.t - q.time) <= 15.0]
        steps = near or sorted(steps, key=lambda s: abs(s.t - q.time))[:5]
    steps = steps[:12]
    if not steps:
        return OpenAnswer(**base, kind="activity", answer=f"nothing recorded in {video}", in_memory=True,
                          features=_features(0, 0.0, 0.0))
    lines = [LogLine(video=s.video, time_seconds=round(s.t, 2), text=s.text, segment_id=s.segment) for s in steps]
    around = f" around {clock(q.time)}" if q.time is not None else ""
    return OpenAnswer(**base, kind="activity", answer="; ".join(f"{clock(x.time_seconds)} {x.text}" for x in lines),
                      in_memory=True, log=lines, evidence=_ids(steps), support=len(steps), features=_features(len(steps)),
                      detail=f"the activity log of {video}{around}")


_ANSWER = {"place": _place, "time": _time, "count": _count, "yesno": _yesno, "next": _next, "routine": _routine,
           "state": _state, "activity": _activity, "actions": _actions}
