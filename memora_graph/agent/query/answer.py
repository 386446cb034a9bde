"""The typed query answered from one person's typed memory, in the type it asks for.

    from memora_graph.agent.query import answer_question, recall
    with MemoryView.open("banks/epic", "P01") as view:
        a = answer_question(view, "P01", "Where did I last put the chopping board?")   # words
        a = recall(view, "P01", Query(operation="count", subject=Subject(verb="open", objects=["fridge"]),
                                     scope=Scope(videos=["P01_103"])))                  # typed
        a.kind, a.place, a.count, a.evidence, a.confidence

A query (`query.model`) is compiled onto the stores:

- the activity log (`query.log`: every segment's narrated steps at EPIC class level, kept as
  columns with the tool stores; filters run once per distinct wording, runs by array
  comparison: query/steplog.py), cut to the query's scope first (videos, a session, a time window, before / after an event), then read by the
  operation with the selector (first / last / nth / usual / all) and the relation (the actions
  after, before, while or instead of an anchor event);
- the subject resolved in the person's own words (`query.vocabulary`): exact, fuzzy, or widened
  to its class (the answer then says so: "no wok in P22's words; pan 94 times");
- the consolidated stores: storage preferences (where something is usually kept), routines
  through the retrieval tool `get_routine_skill` (the steps of a goal), the entity registry;
- the state history of a video (`_tool_video_events`) for the state of an object at a time.

Every answer is an `OpenAnswer`: the kind, the typed value, the evidence ids, a confidence (a
probability from `open_calibration`), the query it answers, and for "not in memory" which reason:
general knowledge, or a subject absent from this person's memory. A query that makes no sense
(`Query.why_not`) is answered with reason `invalid_query` and why.
"""

from __future__ import annotations

import json
import math
import re
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from memora_graph.agent.query.log import LogStep, StepLog, Steps, action_log, clock, noun_words
from memora_graph.agent.query.steplog import first_order_counts
from memora_graph.agent.query.model import (
    Action, ActionShare, LogLine, MomentValue, ObjectStateEvent, OpenAnswer, PlaceValue, Query, RoutineStep, Subject,
)
from memora_graph.agent.query.vocabulary import Vocabulary, class_words
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.text import counted

NOT_IN_MEMORY = "not in memory"
PUT_VERBS = frozenset({"put", "insert", "throw", "drop"})
TAKE_VERBS = frozenset({"take", "remove"})
MAX_ACTIONS = 3
MAX_EVIDENCE = 20
MAX_LOG = 12  # log lines shown before the list is cut (the answer says how to see the rest)
NEAR = 15.0  # seconds: "at 01:00" reads the log this close to the moment
# the answer's type (the calibration's kind) per operation
KIND = {"where": "place", "when": "time", "which_video": "time", "count": "count", "exists": "yesno",
        "list": "actions", "next": "next", "previous": "next", "steps": "routine", "state": "state",
        "duration": "count"}


@dataclass
class _Ask:
    """A query compiled for the log: the subject as classes (and the person's words to match),
    the scope resolved to videos and times."""

    query: Query
    kind: str
    verbs: list[str] = field(default_factory=list)
    nouns: list[str] = field(default_factory=list)
    place: str | None = None
    order: str = "usual"
    source: bool = False
    unit: str = "times"
    videos: list[str] = field(default_factory=list)
    time: float | None = None
    surface: list[str] = field(default_factory=list)  # words of the person's a step must say ('v60')
    widened: str = ""
    unknown: list[str] = field(default_factory=list)

    @property
    def verb(self) -> str | None:
        return self.verbs[0] if self.verbs else None


_NAMES: dict = {}  # class -> the person's word for it, while one answer is composed


def _name(noun: str | None) -> str:
    return _NAMES.get(noun) or noun_words(noun or "")


def _text(verb: str | None, noun: str | None) -> str:
    v = (verb or "").replace("-", " ")
    return f"{v} {_name(noun)}".strip() if noun else v


# -- compiling a query ---------------------------------------------------------------------------------

def _verb_class(word: str | None, lex: Lexicon) -> str | None:
    if not word:
        return None
    return lex.verb(word) or lex.verb_class(word) or word


def _resolve_objects(objects: list[str], words: list[str], vocab: Vocabulary, lex: Lexicon, who: str,
                     log_nouns: set[str]) -> tuple[list[str], list[str], str, list[str]]:
    """(classes, surface words, widening note, unknown words) of a subject's objects."""
    classes, surface, unknown, notes = [], [], [], []
    keys = set(lex.noun_keys)
    for obj in objects:
        if obj in keys:
            classes.append(obj)
            continue
        r = vocab.resolve(obj, lex)
        if r.how in ("exact", "fuzzy") and not r.classes:
            surface.append(r.word)
        elif r.classes:
            classes.append(r.classes[0])
        else:
            unknown.append(obj)
    # the question's own words for its classes: did the person ever say them?
    for c in classes[:1]:
        asked = [w for w in words if c in lex.noun_classes(w)]
        if not asked or any(vocab.says(w) or set(lex.lemmas(w)) & class_words(c) or w in class_words(c)
                            for w in asked):
            continue
        if any(vocab.resolve(w, lex).how == "exact" for w in asked):
            continue
        said = vocab.name(c)
        if c in log_nouns:
            notes.append(f"no {asked[0]} in {who}'s words; read as its class, {said or _name(c)}")
    for w in words:  # a word of theirs no class knows (their name for a thing: 'v60')
        if not lex.noun_classes(w) and vocab.says(w) and w not in surface and not lex.verb_class(w):
            surface.append(w)
    return classes, surface, "; ".join(notes), unknown


def _compile(q: Query, view, participant: str, vocab: Vocabulary, lex: Lexicon, log: StepLog) -> _Ask:
    s = q.subject
    log_nouns = log.nouns
    classes, surface, widened, unknown = _resolve_objects(list(s.objects), list(s.words), vocab, lex, participant,
                                                          log_nouns)
    order = {"first": "first", "last": "last"}.get(q.selector, "usual")
    place = None
    if s.place:
        place = s.place if s.place in lex.noun_keys else (lex.noun_classes(s.place) or [s.place])[0]
    kind = KIND[q.operation]
    if q.operation == "list" and q.selector != "usual":
        kind = "activity"
    scope = q.scope
    return _Ask(query=q, kind=kind, verbs=[v for v in [_verb_class(s.verb, lex)] if v], nouns=classes, place=place,
                order=order, source=s.source, unit=q.unit, videos=list(scope.videos),
                time=scope.at if scope.at is not None else scope.end, surface=surface, widened=widened,
                unknown=[w for w in q.unknown if not vocab.says(w)] + unknown)


def _anchor_ask(q: Query, participant: str, vocab: Vocabulary, lex: Lexicon, log: StepLog) -> _Ask | None:
    a = q.anchor
    if a is None:
        return None
    classes, surface, _, _ = _resolve_objects(list(a.objects), list(a.words), vocab, lex, participant, set())
    return _Ask(query=q, kind="next", verbs=[v for v in [_verb_class(a.verb, lex)] if v], nouns=classes,
                surface=surface)


def _session_videos(view, scope) -> list[str]:
    videos = sorted(view.videos)
    if scope.session is None or not videos:
        return []
    i = scope.session
    if i == -1:
        return videos[-1:]
    return videos[i - 1:i] if 1 <= i <= len(videos) else []


def _scoped(log: StepLog, q: Query, view, anchor: _Ask | None, vocab_lex) -> Steps:
    """The log cut to the query's scope (videos, session, window, before / after an event)."""
    sc = q.scope
    rows = log.rows
    videos = set(sc.videos) | set(_session_videos(view, sc))
    if videos:  # the log is in video order: each video's steps are one range of it
        parts = [np.arange(*rows.video_range(v)) for v in sorted(videos)]
        out = Steps(log, np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64))
    else:
        out = log.all
    if sc.start is not None:
        out = out.keep(out.t >= sc.start - 1e-6)
    if sc.end is not None:
        out = out.keep(out.t <= sc.end + 1e-6)
    if sc.at is not None:
        if q.operation == "list":
            near = np.abs(out.t - sc.at) <= NEAR
            out = out.keep(near) if near.any() else \
                Steps(log, out.at[np.argsort(np.abs(out.t - sc.at), kind="stable")[:5]])
        else:
            out = out.keep(out.t <= sc.at + 1e-6)
    for side, ev in (("after", sc.after), ("before", sc.before)):
        if ev is None:
            continue
        lex = vocab_lex
        cls = [n for n in ev.objects if n in lex.noun_keys] or [c for o in ev.objects for c in lex.noun_classes(o)][:1]
        ask = _Ask(query=q, kind="next", verbs=[v for v in [_verb_class(ev.verb, lex)] if v], nouns=cls)
        hit = out.mask(_matcher(ask, True))
        t, v = out.t, out.video_ix
        marks = np.full(len(rows.videos), np.inf if side == "after" else -np.inf)
        if side == "after":  # after the event's first time in the video
            np.minimum.at(marks, v[hit], t[hit])
            out = out.keep(t > marks[v])
        else:  # before its last
            np.maximum.at(marks, v[hit], t[hit])
            out = out.keep(t < marks[v])
    return out


# -- matching ------------------------------------------------------------------------------------------

def _subject(q: _Ask) -> list[str]:
    """The objects asked about (a place the question names is context, not subject)."""
    return [n for n in q.nouns if n != q.place] or list(q.nouns)


def _label(q: _Ask) -> str | None:
    """What the answer calls the subject: its class in the person's words, or their own word."""
    s = _subject(q)
    return s[0] if s else (q.surface[0] if q.surface else None)


GENERIC_VERBS = frozenset({"use"})  # "does P use the kettle": any action with it


def _verb_ok(want: str | None, have: str | None, loose: bool) -> bool:
    if want is None or want in GENERIC_VERBS:
        return True
    if have == want:
        return True
    return loose and have is not None and want in PUT_VERBS and have in PUT_VERBS


_SAYS: dict[tuple[str, str], bool] = {}


def _says(text: str, word: str) -> bool:
    key = (text, word)
    got = _SAYS.get(key)
    if got is None:
        if len(_SAYS) > 200_000:
            _SAYS.clear()
        got = _SAYS[key] = bool(re.search(rf"(?<![a-z0-9]){re.escape(word)}(?![a-z0-9])", text.lower()))
    return got


def _matches(s: LogStep, q: _Ask, loose: bool = False) -> bool:
    return _matcher(q, loose)(s)


def _matcher(q: _Ask, loose: bool = False):
    """Whether a step is what `q` asks about, as a function of the step (what the query fixes is
    read once: the log's filters call it once per distinct wording)."""
    subject = _subject(q)
    first = subject[0] if subject else None
    want, surface, place = q.verb, tuple(q.surface), q.place
    generic = want is None or want in GENERIC_VERBS
    need_place = bool(place) and (place in subject[1:] or place not in subject)

    def match(s: LogStep) -> bool:
        if not _verb_ok(want, s.verb, loose):
            return False
        if surface and not any(_says(s.text, w) for w in surface):
            return False
        if first is not None and not (first in s.objects or (generic and first in s.nouns)):
            return False
        return not (need_place and place not in s.nouns)
    return match


def _records(log: StepLog, q: _Ask, ids: list[str]) -> list[LogLine]:
    """The steps of the cited segments that the question is about (else the segment's steps)."""
    steps = list(log.of_segments(ids))
    about = [s for s in steps if _matches(s, q, loose=True)] or [s for s in steps if set(_subject(q)) & set(s.nouns)]
    return [LogLine(video=s.video, time_seconds=round(s.t, 2), text=s.text, segment_id=s.segment)
            for s in (about or steps)][:MAX_EVIDENCE]


def _ids(steps: list[LogStep] | Steps) -> list[str]:
    if isinstance(steps, Steps):
        return steps.segment_ids(MAX_EVIDENCE)
    return list(dict.fromkeys(s.segment for s in steps))[:MAX_EVIDENCE]


def _line(s: LogStep) -> LogLine:
    return LogLine(video=s.video, time_seconds=round(s.t, 2), text=s.text, segment_id=s.segment)


# -- answering -----------------------------------------------------------------------------------------

def answer_question(view, participant: str, question: str, lex: Lexicon | None = None) -> OpenAnswer:
    """Answer a question in words: parsed into a `Query` (`query.parse`), its misspellings read
    as the person's own words, then `recall`."""
    from memora_graph.agent.query.parse import parse

    lex = lex or Lexicon.load()
    q = parse(question, lex)
    if q.unknown:
        vocab = Vocabulary.of(view, lex)
        fixed = question
        for w in q.unknown:
            r = vocab.resolve(w, lex)
            if r.how == "fuzzy" and (r.count or r.word in lex.known):  # a slip for a word of theirs or the lexicon
                fixed = re.sub(rf"\b{re.escape(w)}\b", r.word, fixed, flags=re.I)
        if fixed != question:
            q = parse(fixed, lex)
    return recall(view, participant, q, lex, question=question)


answer_open = answer_question  # the name the benchmark and older callers use


def recall(view, participant: str, query: Query | dict, lex: Lexicon | None = None, question: str = "") -> OpenAnswer:
    """Answer a typed query from `view` (a `MemoryView` of `participant`): no words are parsed."""
    global _NAMES
    lex = lex or Lexicon.load()
    q = _normal(query if isinstance(query, Query) else Query.model_validate(query))
    log = action_log(view, lex)
    vocab = Vocabulary.of(view, lex, log)
    ask = _compile(q, view, participant, vocab, lex, log)
    base = {"question": question or q.text, "participant": participant, "asked": q.operation,
            "subject": {"verbs": list(ask.verbs), "nouns": list(ask.nouns), "words": list(ask.surface)},
            "query": q.model_dump(mode="json", exclude_defaults=True)}
    _NAMES = {c: n for c, cnt in vocab.names.items() for n in [cnt.most_common(1)[0][0]] if cnt}
    for w in [*q.subject.words, *(q.anchor.words if q.anchor else [])]:  # the question's word, when it is theirs
        for c in lex.noun_classes(w)[:1]:
            r = vocab.resolve(w, lex)
            if r.how == "exact" and c in r.classes:  # "mugs": their word is "mug"
                _NAMES[c] = r.word
    try:
        why = q.why_not()
        if why:
            answer = _nim(base, "invalid_query", why)
        else:
            anchor = _anchor_ask(q, participant, vocab, lex, log)
            answer = _not_in_memory(view, participant, q, ask, anchor, log, base)
            if answer is None:
                scoped = _scoped(log, q, view, anchor, lex)
                answer = _dispatch(view, q, ask, anchor, scoped, log.all, lex, base)
                if ask.widened:
                    answer.widened = ask.widened
                    answer.answer = f"{answer.answer} ({ask.widened})"
                    answer.features["exact"] = 0.0
        if answer.in_memory and not answer.records and answer.evidence:
            answer.records = _records(log, ask, answer.evidence)
    finally:
        _NAMES = {}
    from memora_graph.agent.open_calibration import calibrate

    answer.confidence = calibrate(answer)
    return answer


def _normal(q: Query) -> Query:
    """A typed query as the parser would have written it: next / previous of a subject read as the
    actions after / before it (the subject is the anchor)."""
    if q.operation in ("next", "previous") and q.anchor is None and not q.subject.empty():
        a = q.subject
        return q.model_copy(update={"anchor": Action(verb=a.verb, objects=a.objects, words=a.words),
                                    "relation": "after" if q.operation == "next" else "before",
                                    "subject": Subject()})
    if q.operation in ("next", "previous") and q.anchor is not None and q.relation is None:
        return q.model_copy(update={"relation": "after" if q.operation == "next" else "before"})
    return q


def _dispatch(view, q: Query, ask: _Ask, anchor: _Ask | None, log: Steps, whole: Steps, lex: Lexicon,
              base: dict) -> OpenAnswer:
    op = q.operation
    if q.relation in ("after", "before") and anchor is not None:
        return _around(view, ask, anchor, log, lex, base, after=q.relation == "after")
    if q.relation == "while" and anchor is not None:
        return _while(view, ask, anchor, log, lex, base)
    if q.relation == "instead_of" and anchor is not None:
        return _instead(view, ask, anchor, log, lex, base)
    if op == "where":
        return _place(view, ask, log, lex, base)
    if op in ("when", "which_video"):
        return _time(view, ask, log, lex, base)
    if op == "count":
        return _count(view, ask, log, lex, base)
    if op == "exists":
        return _yesno(view, ask, log, lex, base)
    if op in ("next", "previous"):
        return _actions(view, ask, log, lex, base)
    if op == "steps":
        return _routine(view, ask, log, lex, base)
    if op == "state":
        return _state(view, ask, whole, lex, base)
    if op == "duration":
        return _duration(view, ask, log, lex, base)
    if q.selector in ("first", "last", "nth"):
        return _one_step(view, ask, log, lex, base)
    if q.selector == "all" or not (ask.nouns or ask.verbs or ask.surface):
        return _activity(view, ask, log, lex, base)
    return _actions(view, ask, log, lex, base)


def _nim(base: dict, reason: str, detail: str, **features) -> OpenAnswer:
    return OpenAnswer(**base, kind="not_in_memory", answer=NOT_IN_MEMORY if reason != "invalid_query" else
                      f"cannot answer: {detail}", in_memory=False, reason=reason, detail=detail,
                      features={"nim": 1.0, **features})


def _not_in_memory(view, participant: str, q: Query, ask: _Ask, anchor: _Ask | None, log: StepLog,
                   base: dict) -> OpenAnswer | None:
    if q.world:
        return _nim(base, "general_knowledge", "the question asks about the world, not about what this person did")
    if q.person and q.person != participant:
        return _nim(base, "absent_subject", f"the question is about {q.person}; this is {participant}'s memory")
    missing = [v for v in q.scope.videos if v not in view.videos]
    if missing:
        return _nim(base, "absent_subject", f"no video {', '.join(missing)} in {participant}'s memory")
    if q.scope.session is not None and not _session_videos(view, q.scope):
        return _nim(base, "absent_subject", f"{participant}'s memory has {len(view.videos)} sessions")
    nouns, verbs = log.nouns, log.verbs
    if anchor is not None and q.relation:
        asub = _subject(anchor)
        if asub and asub[0] not in nouns:
            return _nim(base, "absent_subject", f"no {_name(asub[0])} in {participant}'s memory")
        if not asub and not anchor.surface and anchor.verb and anchor.verb not in verbs:
            return _nim(base, "absent_subject", f"{participant} is never seen to {anchor.verb}")
        return None
    if q.operation in ("list", "state", "duration") and (q.scope.videos or q.scope.session) and \
            not (ask.nouns or ask.surface):
        return None
    if q.operation == "list" and q.selector != "usual" and not (ask.nouns or ask.surface or ask.verbs):
        return None
    if q.operation == "steps" and q.subject.goal:
        return None
    subject = _subject(ask)
    if ask.surface and not subject:
        return None
    if not subject and (not ask.verbs or set(ask.verbs) <= GENERIC_VERBS):
        what = ", ".join(ask.unknown) if ask.unknown else "what the question names"
        return _nim(base, "absent_subject", f"{what}: no such action or object in {participant}'s memory")
    if subject and subject[0] not in nouns:
        return _nim(base, "absent_subject", f"no {_name(subject[0])} in {participant}'s memory")
    if not subject and ask.verb and ask.verb not in verbs:
        return _nim(base, "absent_subject", f"{participant} is never seen to {ask.verb}")
    if q.operation == "exists" and ask.unknown and not subject:
        return _nim(base, "absent_subject", f"no {', '.join(ask.unknown)} in {participant}'s memory")
    return None


def _features(support: int, share: float = 1.0, margin: float = 1.0, fallback: bool = False, exact: bool = True) -> dict:
    return {"log_support": math.log1p(max(0, support)), "share": float(share), "margin": float(margin),
            "fallback": 1.0 if fallback else 0.0, "exact": 1.0 if exact else 0.0}


def _place(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    subject = _subject(q)
    noun = subject[0] if subject else None
    verbs = TAKE_VERBS if q.source else PUT_VERBS
    cands = log.where(lambda s: s.place and noun in s.objects and s.verb in verbs and s.place != noun)
    what = _name(noun) if noun else "it"
    if cands:
        if q.order in ("last", "first"):
            s = cands[-1] if q.order == "last" else cands[0]
            total = cands.count_by(lambda c: c.place)
            pv = PlaceValue(place=s.place, name=_name(s.place), video=s.video, time_seconds=round(s.t, 2),
                            count=total[s.place], share=round(total[s.place] / len(cands), 3))
            word = "last" if q.order == "last" else "first"
            verb = "took" if q.source else "put"
            text = f"{pv.name} ({word} {verb} there in {s.video} at {clock(s.t)})"
            return OpenAnswer(**base, kind="place", answer=text, in_memory=True, place=pv, evidence=[s.segment],
                              support=len(cands), detail=f"{counted(len(cands), 'placement')} of the {what} in memory",
                              features=_features(len(cands), 1.0, 1.0))
        counts = cands.count_by(lambda c: c.place)
        (best, n), *rest = counts.most_common()
        share = n / len(cands)
        margin = share - (rest[0][1] / len(cands) if rest else 0.0)
        at_best = cands.where(lambda c: c.place == best)
        last = at_best[-1]
        pv = PlaceValue(place=best, name=_name(best), video=last.video, time_seconds=round(last.t, 2), count=n,
                        share=round(share, 3))
        prefs = _storage_prefs(view, noun, lex)
        text = f"{pv.name} ({n} of {len(cands)} times, {share:.0%}; last in {last.video} at {clock(last.t)})"
        return OpenAnswer(**base, kind="place", answer=text, in_memory=True, place=pv,
                          evidence=_ids(at_best) + [p["id"] for p in prefs][:3],
                          support=n, detail=f"where the {what} was {'taken from' if q.source else 'put'}, by count",
                          features=_features(n, share, margin, exact=False))
    if not q.query.scope.empty():
        return _place_in_scope(view, q, log, lex, base, noun, what)
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
            counts = taken.count_by(lambda c: c.place)
            best, n = counts.most_common(1)[0]
            at_best = taken.where(lambda c: c.place == best)
            last = at_best[-1]
            pv = PlaceValue(place=best, name=_name(best), video=last.video, time_seconds=round(last.t, 2), count=n,
                            share=round(n / len(taken), 3))
            return OpenAnswer(**base, kind="place", answer=f"{pv.name} (taken from there {n} of {len(taken)} times)",
                              in_memory=True, place=pv, evidence=_ids(at_best),
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
        pv = PlaceValue(place=s.place, name=_name(s.place), video=s.video, time_seconds=round(s.t, 2), count=1)
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


def _time(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    hits = log.where(_matcher(q))
    exact = True
    if not hits:
        hits = log.where(_matcher(q, True))
        exact = False
    if not hits:
        return _never(q, base)
    nth = q.query.nth if q.query.selector == "nth" else None
    if nth is not None and nth > len(hits):
        return OpenAnswer(**base, kind="time", answer=f"only {counted(len(hits), 'time')} recorded, no {_ordinal(nth)} time",
                          in_memory=True, support=len(hits), evidence=_ids(hits), features=_features(len(hits), 0.5, 0.0))
    s = hits[nth - 1] if nth else hits[0] if q.order == "first" else hits[-1]
    word = _ordinal(nth) if nth else "first" if q.order == "first" else "last"
    videos = hits.videos()
    m = MomentValue(video=s.video, time_seconds=round(s.t, 2), clock=clock(s.t))
    return OpenAnswer(**base, kind="time", answer=f"{s.video} at {m.clock} ({word} of {counted(len(hits), 'time')}, in "
                      f"{counted(len(videos), 'video')})", in_memory=True, moment=m, evidence=[s.segment], support=len(hits),
                      detail=f"{s.text} ({word} time)", features=_features(len(hits), 1.0, 1.0, exact=exact))


def _never(q: _Ask, base: dict) -> OpenAnswer:
    asked = _text(q.verb, _label(q))
    return OpenAnswer(**base, kind=q.kind, answer=f"never recorded: {asked}",
                      in_memory=True, yes=False if q.kind == "yesno" else None, count=0 if q.kind == "count" else None,
                      detail=f"its objects are in memory, never with this action ({asked})",
                      features=_features(0, 0.0, 0.0))


def _count(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    hits = log.where(_matcher(q))
    if not hits:
        return _never(q, base)
    videos = hits.videos()
    n = len(videos) if q.unit == "videos" else len(hits)
    unit = "video" if q.unit == "videos" else "time"
    asked = _text(q.verb, _label(q))
    return OpenAnswer(**base, kind="count", answer=f"{counted(n, unit)} ({asked}; {counted(len(hits), 'record')} in {counted(len(videos), 'video')})",
                      in_memory=True, count=n, evidence=_ids(hits), support=len(hits),
                      detail=f"counted {counted(len(hits), 'record')} of '{asked}'", features=_features(len(hits), 1.0, 1.0))


def _yesno(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    hits = log.where(_matcher(q))
    if not hits and q.query.scope.empty():  # over all memory, a put of any kind answers "did P put X"
        hits = log.where(_matcher(q, True))
    if not hits:
        return _never(q, base)
    if q.widened:  # "has P22 ever used a wok?": no row says wok; the class (pan) is the widened reading
        cls = _subject(q)[0] if _subject(q) else ""
        return OpenAnswer(**base, kind="yesno", answer=f"no: {q.widened}, {_name(cls)} {counted(len(hits), 'time')}",
                          in_memory=True, yes=False, evidence=_ids(hits), support=len(hits),
                          detail=f"the person never names it so; its class {_name(cls)} is recorded",
                          features=_features(len(hits), 0.5, 0.0, exact=False))
    videos = hits.videos()
    return OpenAnswer(**base, kind="yesno", answer=f"yes ({counted(len(hits), 'time')} in {counted(len(videos), 'video')}; last in "
                      f"{hits[-1].video} at {clock(hits[-1].t)}: {hits[-1].text})", in_memory=True, yes=True,
                      evidence=_ids(hits), support=len(hits), detail=hits[-1].text, features=_features(len(hits)))


def _shares(counts: Counter, total: int) -> list[ActionShare]:
    return [ActionShare(verb=v or "", noun=n or "", text=_text(v, n), count=c, share=round(c / total, 3))
            for (v, n), c in counts.most_common(MAX_ACTIONS)]


def _triggers(t: _Ask):
    """Whether a step is the anchor event `t`, as a function of the step."""
    subject = _subject(t)
    first = subject[0] if subject else None
    verb = t.verb if t.verb and t.verb not in GENERIC_VERBS else None
    surface = tuple(t.surface)

    def trigger(s: LogStep) -> bool:
        if verb is not None and s.verb != verb:
            return False
        if first is not None and first not in s.objects:
            return False
        return not surface or any(_says(s.text, w) for w in surface)
    return trigger


def _around(view, q: _Ask, anchor: _Ask, log: Steps, lex: Lexicon, base: dict, after: bool) -> OpenAnswer:
    """The actions right after (or before) the anchor event, by how often they follow (precede) it."""
    whole = log.log
    a, b = log.run_pairs()  # each two runs of one video that follow each other, in order
    if not after:
        a, b = b, a
    trig = whole.word_mask(_triggers(anchor))
    word = whole.rows.word
    keep = trig[word[a]] & ~trig[word[b]]  # the event itself again is no answer
    if q.nouns or q.surface or (q.verb and q.verb not in GENERIC_VERBS):
        keep &= whole.word_mask(_matcher(q, True))[word[b]]
    got = Steps(whole, b[keep])
    counts = got.action_counts()
    if not counts:
        return _never(anchor, base) if anchor.verb else _actions(view, anchor, log, lex, base)
    top = [key for key, _ in counts.most_common(MAX_ACTIONS)]
    names, keys = whole.pairs()[0], whole.pair_ids(got.at)
    seen = {key: list(got.keep(keys == names.index(key))[:5]) for key in top}  # the first few of each action
    total = sum(counts.values())
    acts = _shares(counts, total)
    margin = acts[0].share - (acts[1].share if len(acts) > 1 else 0.0)
    subject = _subject(anchor)
    trig = _text(anchor.verb, subject[0] if subject else (anchor.surface[0] if anchor.surface else None))
    text = "; ".join(f"{a.text} ({a.share:.0%})" for a in acts)
    shown = [st for key in top for st in seen[key]]
    word = "followed" if after else "came just before"
    return OpenAnswer(**base, kind="next", answer=text, in_memory=True, actions=acts, records=[_line(x) for x in shown],
                      evidence=list(dict.fromkeys(st.segment for key in top for st in seen[key])),
                      support=acts[0].count, detail=f"what {word} '{trig}' in {total} cases",
                      features=_features(acts[0].count, acts[0].share, margin, exact=False))


WHILE_SLACK = 5.0  # seconds either side of the anchor's run that count as "while"


def _while(view, q: _Ask, anchor: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    """The actions done during the anchor event (its runs, a few seconds either side)."""
    whole = log.log
    t, v = log.t, log.video_ix
    starts, ends = log.run_starts(), log.run_ends()
    runs = log.runs_where(_triggers(anchor))
    if not len(runs) and anchor.verb and _subject(anchor):  # "while the kettle boils": the kettle's events
        anchor = _Ask(query=anchor.query, kind=anchor.kind, nouns=anchor.nouns, surface=anchor.surface)
        runs = log.runs_where(_triggers(anchor))
    if not len(runs):
        return _never(anchor, base)
    # each run's span, a few seconds either side; a step is in one when it is in their union (per video)
    span_v = v[starts[runs]]
    lo, hi = t[starts[runs]] - WHILE_SLACK, t[ends[runs]] + WHILE_SLACK
    inside = np.zeros(len(log), dtype=bool)
    for video in np.unique(span_v).tolist():
        mine = span_v == video
        order = np.argsort(lo[mine], kind="stable")
        a, b = lo[mine][order], np.maximum.accumulate(hi[mine][order])  # the furthest end of the spans so far
        at = np.flatnonzero(v == video)
        k = np.searchsorted(a, t[at], "right") - 1  # the last span starting at or before the step
        inside[at] = (k >= 0) & (t[at] <= b[np.maximum(k, 0)])
    keep = inside & ~log.mask(_triggers(anchor))
    if q.nouns or q.surface:
        keep &= log.mask(_matcher(q, True))
    hits = log.keep(keep)
    if not hits:
        return OpenAnswer(**base, kind="actions", answer="nothing else recorded while it happened", in_memory=True,
                          support=0, features=_features(0, 0.0, 0.0))
    counts = hits.action_counts()
    acts = _shares(counts, len(hits))
    margin = acts[0].share - (acts[1].share if len(acts) > 1 else 0.0)
    return OpenAnswer(**base, kind="actions", answer="; ".join(f"{a.text} ({a.share:.0%})" for a in acts),
                      in_memory=True, actions=acts, evidence=_ids(hits), support=acts[0].count,
                      detail=f"what was done during {len(runs)} occurrences of the event",
                      features=_features(acts[0].count, acts[0].share, margin, exact=False))


def _first_segments(steps: Steps, keys: list[tuple], n: int = 5) -> dict[tuple, list[str]]:
    """The segments of the first `n` of `steps` with each action (verb, first object) of `keys`."""
    names, of = steps.log.pairs()[0], steps.log.pair_ids(steps.at)
    return {k: [s.segment for s in steps.keep(of == names.index(k))[:n]] for k in keys}


def _instead(view, q: _Ask, anchor: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    """What takes the anchor's place: the same action on another object, after the same action
    that usually precedes the anchor (else the same action on other objects)."""
    obj = (_subject(anchor) or [None])[0]
    if obj and (not anchor.verb or anchor.verb in GENERIC_VERBS):
        return _instead_object(view, q, anchor, obj, log, lex, base)
    whole = log.log
    word, run_key = whole.rows.word, whole.run_keys()
    a, b = log.run_pairs()  # each two runs of one video that follow each other, in order
    trig = whole.word_mask(_triggers(anchor))
    before = Counter(dict(first_order_counts(run_key[word[a[trig[word[b]]]]])))
    contexts = np.asarray([k for k, _ in before.most_common(3)], dtype=np.int64)
    verb = anchor.verb
    fits = whole.word_mask(lambda x: bool(x.objects) and not (verb and verb not in GENERIC_VERBS and x.verb != verb))
    keep = ~trig[word[b]] & fits[word[b]] & np.isin(run_key[word[a]], contexts)
    got = Steps(whole, b[keep])
    how = "in the same place in the sequence"
    if not got:
        subj = (_subject(anchor) or [None])[0]
        trigger = _triggers(anchor)
        got = log.where(lambda x: bool(x.objects) and not trigger(x) and
                        (not verb or verb in GENERIC_VERBS or x.verb == verb) and lex.same_category(x.objects[0], subj))
        how = "the same action on things of the same kind"
    alt = got.action_counts()
    if not alt:
        return OpenAnswer(**base, kind="actions", answer="nothing recorded in its place", in_memory=True,
                          features=_features(0, 0.0, 0.0))
    total = sum(alt.values())
    acts = _shares(alt, total)
    margin = acts[0].share - (acts[1].share if len(acts) > 1 else 0.0)
    top = [k for k, _ in alt.most_common(MAX_ACTIONS)]
    ids = _first_segments(got, top)
    return OpenAnswer(**base, kind="actions", answer="; ".join(f"{a.text} ({a.share:.0%})" for a in acts),
                      in_memory=True, actions=acts, support=acts[0].count,
                      evidence=list(dict.fromkeys(i for k in top for i in ids[k])),
                      detail=f"instead of it: {how}", features=_features(acts[0].count, acts[0].share, margin, exact=False))


def _instead_object(view, q: _Ask, anchor: _Ask, obj: str, log: Steps, lex: Lexicon,
                    base: dict) -> OpenAnswer:
    """Objects of the anchor's kind used for what the anchor is used for ("instead of the knife")."""
    uses = log.where(lambda s: obj in s.objects and s.verb).count_by(lambda s: s.verb)
    top = {v for v, _ in uses.most_common(3) if v not in ("take", "put", "move", "hold")} or \
        {v for v, _ in uses.most_common(3)}
    got = log.where(lambda s: s.verb in top and bool(s.objects) and s.objects[0] != obj and
                    lex.same_category(s.objects[0], obj))
    alt = got.action_counts()
    if not alt:
        return OpenAnswer(**base, kind="actions", answer=f"nothing of its kind used in place of the {_name(obj)}",
                          in_memory=True, features=_features(0, 0.0, 0.0))
    total = sum(alt.values())
    acts = _shares(alt, total)
    margin = acts[0].share - (acts[1].share if len(acts) > 1 else 0.0)
    keys = [k for k, _ in alt.most_common(MAX_ACTIONS)]
    ids = _first_segments(got, keys)
    return OpenAnswer(**base, kind="actions", answer="; ".join(f"{a.text} ({a.share:.0%})" for a in acts),
                      in_memory=True, actions=acts, support=acts[0].count,
                      evidence=list(dict.fromkeys(i for k in keys for i in ids[k])),
                      detail=f"things of the {_name(obj)}'s kind used for what it is used for "
                             f"({', '.join(sorted(top))})", features=_features(acts[0].count, acts[0].share, margin,
                                                                              exact=False))


def _ordinal(n: int | None) -> str:
    return {1: "first", 2: "second", 3: "third"}.get(n or 0, f"{n}th")


def _one_step(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    """The first / last / nth thing done in the scope (of the subject, when there is one)."""
    steps = log.where(_matcher(q, True)) if (q.nouns or q.surface or q.verbs) else log
    if not steps:
        return _never(q, base) if (q.nouns or q.verbs) else OpenAnswer(
            **base, kind="activity", answer="nothing recorded there", in_memory=True, features=_features(0, 0.0, 0.0))
    sel = q.query.selector
    nth = q.query.nth or 1
    if sel == "nth" and nth > len(steps):
        return OpenAnswer(**base, kind="activity", answer=f"only {len(steps)} steps recorded, no {_ordinal(nth)}",
                          in_memory=True, support=len(steps), features=_features(len(steps), 0.5, 0.0))
    s = steps[-1] if sel == "last" else steps[nth - 1] if sel == "nth" else steps[0]
    word = _ordinal(nth) if sel == "nth" else sel
    m = MomentValue(video=s.video, time_seconds=round(s.t, 2), clock=clock(s.t))
    acts = [ActionShare(verb=s.verb or "", noun=s.objects[0] if s.objects else "", text=s.text, count=1, share=1.0)]
    return OpenAnswer(**base, kind="activity", answer=f"{s.text} ({s.video} at {m.clock}, the {word} of {len(steps)} "
                      f"steps)", in_memory=True, moment=m, log=[_line(s)], actions=acts, evidence=[s.segment],
                      support=len(steps), detail=f"the {word} step in the scope", features=_features(len(steps)))


DURATION_CAP = 60.0  # seconds: a step's duration runs to the next step, at most this long


def _duration(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    """Seconds spent on the subject (each matching step until the next step of its video), or
    the span of the scope's log when no subject is named."""
    if not (q.nouns or q.surface or q.verbs):
        if not log:
            return OpenAnswer(**base, kind="duration", answer="nothing recorded there", in_memory=True,
                              features=_features(0, 0.0, 0.0))
        v, t = log.video_ix, log.t
        first = log.keep(np.r_[True, v[1:] != v[:-1]]).video_ix.tolist()
        lo, hi = np.full(len(log.log.rows.videos), np.inf), np.full(len(log.log.rows.videos), -np.inf)
        np.minimum.at(lo, v, t)
        np.maximum.at(hi, v, t)
        spans = {k: (float(lo[k]), float(hi[k])) for k in first}  # each video's first and last step, in order
        total = sum(b - a for a, b in spans.values())
        return OpenAnswer(**base, kind="duration", answer=f"{clock(total)} ({total:.0f} s from the first to the last "
                          f"step, {counted(len(spans), 'video')})", in_memory=True, seconds=round(total, 1), count=round(total),
                          evidence=_ids(Steps(log.log, log.at[[0, -1]])), support=len(log), features=_features(len(log)))
    idx = np.flatnonzero(log.mask(_matcher(q, True)))
    v, t = log.video_ix, log.t
    nxt = idx + 1
    has = nxt < len(log)
    has[has] = v[nxt[has]] == v[idx[has]]  # the next step of its video
    spent = np.minimum(DURATION_CAP, np.where(has, t[np.minimum(nxt, len(log) - 1)] - t[idx], 2.0))
    total = 0.0
    for x in spent.tolist():  # added in order, as the answer always added them
        total += x
    hits = log.keep(idx)
    if not hits:
        return _never(q, base)
    videos = len(hits.videos())
    return OpenAnswer(**base, kind="duration", answer=f"{clock(total)} ({total:.0f} s over {counted(len(hits), 'step')} in "
                      f"{counted(videos, 'video')})", in_memory=True, seconds=round(total, 1), count=round(total), evidence=_ids(hits),
                      support=len(hits), detail="each step until the next one, at most 60 s",
                      features=_features(len(hits), 1.0, 1.0))


def _place_in_scope(view, q: _Ask, log: Steps, lex: Lexicon, base: dict, noun: str | None,
                    what: str) -> OpenAnswer:
    """Where the object was in the scope when no placement there says so: its state history at
    the moment asked (a video's), else the place it was last seen with there."""
    videos = list(q.query.scope.videos) or _session_videos(view, q.query.scope)
    if videos and noun:
        got = _state(view, q, log, lex, base)
        for st in got.states:
            if st.location:
                loc = st.location.replace("_", " ")
                place = (lex.noun_classes(loc) or [st.location])[0]
                pv = PlaceValue(place=place, name=_name(place) if place in lex.noun_keys else loc, video=st.video,
                                time_seconds=st.time_seconds, count=1)
                return OpenAnswer(**base, kind="place", answer=f"{pv.name} (its state in {st.video} since "
                                  f"{clock(st.time_seconds)})", in_memory=True, place=pv, evidence=[st.event_id],
                                  support=1, detail="the object's state history at the moment asked",
                                  features=_features(1, 0.5, 0.0, True, False))
    seen = log.where(lambda s: noun in s.nouns and s.place and s.place != noun)
    if seen:
        s = seen[-1] if q.order != "first" else seen[0]
        pv = PlaceValue(place=s.place, name=_name(s.place), video=s.video, time_seconds=round(s.t, 2), count=1)
        return OpenAnswer(**base, kind="place", answer=f"{pv.name} (seen with it in {s.video} at {clock(s.t)})",
                          in_memory=True, place=pv, evidence=[s.segment], support=len(seen),
                          detail="no placement in the scope; the place it was last seen with",
                          features=_features(len(seen), 0.5, 0.0, True, False))
    return OpenAnswer(**base, kind="place", answer=f"no place recorded for the {what} in the scope asked",
                      in_memory=True, detail="nothing in the scope says where it was", features=_features(0, 0.0, 0.0, True))


def _actions(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    subject = _subject(q)
    hits = log.where(lambda s: (not subject or subject[0] in s.nouns) and _verb_ok(q.verb, s.verb, True))
    if not hits:
        return _never(q, base)
    counts = hits.action_counts()
    acts = _shares(counts, len(hits))
    margin = acts[0].share - (acts[1].share if len(acts) > 1 else 0.0)
    return OpenAnswer(**base, kind="actions", answer="; ".join(f"{a.text} ({a.share:.0%})" for a in acts),
                      in_memory=True, actions=acts, evidence=_ids(hits), support=acts[0].count,
                      detail=f"the actions recorded with the {_name(subject[0]) if subject else 'subject'}",
                      features=_features(acts[0].count, acts[0].share, margin, exact=False))


ROUTINE_SIMILARITY = 0.5  # a routine found for a goal no class names must be at least this close


def _routine(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    """The steps of a goal: the retrieval tool `get_routine_skill` (so what improves routines there
    improves this), the best routine that shares the goal's objects; else the sequence that most
    often surrounds the goal's action in the episodes."""
    from memora_graph.retrieve.tools import get_routine_skill

    subject = set(_subject(q))
    goal = q.query.subject.goal or _text(q.verb, _subject(q)[0] if subject else None) or " ".join(q.surface)
    best = None
    if goal:
        fits = []
        for r in get_routine_skill(view, goal_query=goal, top_k=5).routines:
            gnouns = {n for c in lex.parse(r.goal) for n in c.nouns} | \
                {n for o in r.key_objects for n in lex.noun_classes(o.object.replace("_", " "))}
            if (subject and subject & gnouns) or (not subject and (r.similarity or 0.0) >= ROUTINE_SIMILARITY):
                fits.append(r)
        # how the person usually does the whole task (its stages) before a run of steps around the object
        named = [r for r in fits if r.kind == "task_routine" and subject & {n for c in lex.parse(r.goal) for n in c.nouns}]
        best = (named or fits or [None])[0]
    if best is not None and best.kind == "task_routine":
        return _task_answer(best, lex, base)
    if best is not None:
        steps = []
        for i, st in enumerate(best.canonical_steps):
            c = next(iter(lex.parse(st.action)), None)
            steps.append(RoutineStep(order=i + 1, verb=(c.verb if c and c.verb else ""),
                                     noun=(c.nouns[0] if c and c.nouns else ""), text=st.action))
        n = int(best.count or 0)
        return OpenAnswer(**base, kind="routine", answer=" -> ".join(s.text for s in steps) +
                          f" (routine '{best.goal}', seen {counted(n, 'time')})", in_memory=True, steps=steps,
                          evidence=[best.routine_id, *best.supporting_episodes[:5]], support=n,
                          detail=f"the consolidated routine '{best.goal}' (get_routine_skill)",
                          features=_features(n, float(best.confidence or 0.5), 1.0, exact=False))
    if q.query.subject.goal and (subject or q.surface) and not q.verb:
        episode = _episode(q, log)  # "how does P09 make tea": the episode that makes it, step by step
        if episode is not None:
            return _episode_answer(q, episode, base)
    # no routine: the steps that most often surround the goal action in the episodes
    windows: Counter = Counter(log.run_windows(
        lambda s: not ((q.verb and s.verb != q.verb) or (subject and not subject & set(s.objects))), 1, 2))
    if not windows:
        return _never(q, base)
    seq, n = windows.most_common(1)[0]
    steps = [RoutineStep(order=i + 1, verb=v or "", noun=o, text=_text(v, o)) for i, (v, o) in enumerate(seq)]
    return OpenAnswer(**base, kind="routine", answer=" -> ".join(s.text for s in steps) + f" (seen {counted(n, 'time')})",
                      in_memory=True, steps=steps, support=n, detail="the most common sequence around it in the episodes",
                      features=_features(n, n / sum(windows.values()), 0.0, True, False))


def _task_answer(r, lex: Lexicon, base: dict) -> OpenAnswer:
    """A recurring task's stages ("setup: open cupboard, take filter; main: pour coffee, ..."), from
    its task routine (canonical steps said "stage: step")."""
    steps, stages = [], {}
    for i, st in enumerate(r.canonical_steps):
        stage, _, text = st.action.partition(": ")
        if not text:
            stage, text = "main", st.action
        c = next(iter(lex.parse(text)), None)
        steps.append(RoutineStep(order=i + 1, verb=(c.verb if c and c.verb else ""),
                                 noun=(c.nouns[0] if c and c.nouns else ""), text=text))
        stages.setdefault(stage, []).append(text)
    n = int(r.count or 0)
    goal = r.goal.split(" (")[0]
    said = "; ".join(f"{stage}: {', '.join(texts)}" for stage, texts in stages.items())
    return OpenAnswer(**base, kind="routine", answer=f"{said} (task '{goal}', done {counted(n, 'time')})",
                      in_memory=True, steps=steps, evidence=[r.routine_id, *r.supporting_episodes[:5]], support=n,
                      detail=f"the person's task '{goal}', its usual stages (get_routine_skill)",
                      features=_features(n, float(r.confidence or 0.5), 1.0, exact=False))


MAX_STEPS = 12
LEAD, TRAIL = 6, 3  # steps before the goal object's first mention and after its last


def _episode(q: _Ask, log: Steps) -> Steps | None:
    """The steps of the video that names the goal's object most, from its first mention to its last."""
    subject = set(_subject(q))
    hit = log.mask(lambda s: subject & set(s.nouns) or any(_says(s.text, w) for w in q.surface))
    if not hit.any():
        return None
    v = log.video_ix
    video = Counter(dict(first_order_counts(v[hit]))).most_common(1)[0][0]
    steps = np.flatnonzero(v == video)  # the video's steps (indexes into the scope's)
    mine = np.flatnonzero(hit & (v == video))
    first, last = np.searchsorted(steps, mine[0]), np.searchsorted(steps, mine[-1])
    # with what leads up to it (the kettle filled before the teabag goes in) and what closes it
    return Steps(log.log, log.at[steps[max(0, first - LEAD):last + 1 + TRAIL]])


def _episode_answer(q: _Ask, episode: Steps, base: dict) -> OpenAnswer:
    starts = episode.run_starts()
    shown = [episode[int(i)] for i in starts[:MAX_STEPS]]
    steps = [RoutineStep(order=i + 1, verb=st.verb or "", noun=st.objects[0] if st.objects else "", text=st.text)
             for i, st in enumerate(shown)]
    video = episode[0].video
    cut = ""
    if len(starts) > len(shown):
        t = shown[-1].t
        cut = (f"cut: {len(shown)} of {len(starts)} steps shown; ask what happened in {video} between {clock(t)} and "
               f"{clock(episode[-1].t)} for the rest")
    return OpenAnswer(**base, kind="routine", answer=" -> ".join(x.text for x in steps) +
                      f" ({video}, {clock(episode[0].t)}-{clock(episode[-1].t)}; no consolidated routine)" +
                      (f" ({cut})" if cut else ""), in_memory=True, steps=steps, cut=cut, support=1,
                      evidence=_ids(episode), records=[_line(x) for x in shown],
                      detail=f"the episode of {video} that names it most, no routine consolidated for it",
                      features=_features(1, 0.5, 0.0, True, False))


def _state(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    """The objects' state and place in a video at a moment (its end when none is asked); without a
    video, the last one ("is the fridge open now?")."""
    videos = list(q.videos) or _session_videos(view, q.query.scope) or sorted(view.videos)[-1:]
    if not videos:
        return _actions(view, q, log, lex, base)
    video = videos[0]
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
    at = f"at {clock(q.time)}" if q.time is not None else "at its end"
    if not states:
        return OpenAnswer(**base, kind="state", answer=f"nothing recorded about it in {video} {at}", in_memory=True,
                          features=_features(0, 0.0, 0.0))
    text = "; ".join(f"{s.object}: {s.state} at {s.location.replace('_', ' ')} (since {clock(s.time_seconds)})"
                     for s in states)
    return OpenAnswer(**base, kind="state", answer=f"{text} ({video} {at})", in_memory=True, states=states,
                      evidence=[s.event_id for s in states], support=len(states), features=_features(len(states)),
                      detail=f"the state history of {video} {at}")


def _activity(view, q: _Ask, log: Steps, lex: Lexicon, base: dict) -> OpenAnswer:
    """The scope's log in order (about the subject, when one is named); a long one is cut, saying so."""
    steps = log
    subject = set(_subject(q))
    if subject or q.surface:
        steps = steps.where(lambda s: subject & set(s.nouns) or any(_says(s.text, w) for w in q.surface)) or steps
    where = ", ".join(steps.videos()) or "the scope asked"
    if not steps:
        return OpenAnswer(**base, kind="activity", answer=f"nothing recorded in {where}", in_memory=True,
                          features=_features(0, 0.0, 0.0))
    shown = steps[:MAX_LOG]
    lines = [_line(s) for s in shown]
    cut = ""
    if len(steps) > len(shown):
        nxt = shown[-1].t
        cut = (f"cut: {len(shown)} of {len(steps)} steps shown (to {clock(nxt)}); ask with a time window (e.g. "
               f"'between {clock(nxt)} and {clock(nxt + 300)}') or recall with scope.start / scope.end for the rest")
    text = "; ".join(f"{clock(x.time_seconds)} {x.text}" for x in lines)
    return OpenAnswer(**base, kind="activity", answer=text + (f" ({cut})" if cut else ""), in_memory=True, log=lines,
                      cut=cut, evidence=_ids(shown), support=len(steps), features=_features(len(steps)),
                      detail=f"the activity log of {where}")
