"""The typed question reader: a question and its options, read at the level of actions and objects,
scored against typed evidence, answered with the evidence ids, or "not in memory".

1. Question -> `Intent` (`parse_question`): the kind of question (a habit: what follows an action;
   a preference or method; a routine or approach; recall of one video), its action clauses as
   EPIC verb and noun classes (`perceive.lexicon`), the subject objects, the place, the videos it
   names, and the relation asked (next, where, tool, method, order, what happened).
2. Typed evidence -> `Event`s: every record a tool returned, as (video, time, verb class, object
   classes) with the ids of the bank nodes behind it (`evidence.events_of`). Episodes, a
   consolidated habit's trigger and next step, a storage preference's object and place, a
   routine's steps, a Flat-1D text record and a Graph-2D node all become events; the reader does
   not know which memory they came from.
3. Options -> items: each option parsed the same way into (verb, object, place, instrument) items;
   an item all four options share says nothing, one option alone has says most (`_weights`).
4. Scoring (`score`): for a habit, the actions that followed the trigger; for a preference or a
   routine, the actions around the subject (how often each option's items occur there); for
   recall, whether the video holds each of the option's actions, in the option's order.
5. Abstaining: E when memory holds no record of the subject (nothing retrieved mentions it), or
   when the evidence does not separate the options (the best is weak or barely ahead). `ReaderDecision`
   says which.

Deterministic, no language model: a few thousand dictionary lookups per question, plus one
closeness term in meaning (MiniLM cosine between each option and up to `MAX_TEXTS` evidence
records, `SEMANTIC`) that the class-level match outweighs.
"""

from __future__ import annotations

import math
import re
from bisect import bisect_left, bisect_right
from collections import defaultdict
from dataclasses import dataclass, field, replace
from itertools import repeat

from memora_graph.agent.claims import adjust
from memora_graph.agent.claims import enabled as claims_enabled
from memora_graph.perceive.lexicon import Clause, Lexicon

KINDS = ("habit", "preference", "routine", "recall")
OPTION_E = "E"
NO_SITUATION = "no record of the situation asked about"  # the subject is in memory, never in this situation
_VIDEO = re.compile(r"\bP\d{2}_(?:\d{2,3}\b|\?+)")  # a masked id ("P01_???") names a video too
_PARTICIPANT = re.compile(r"\bP\d{2}\b(?:'s)?")
_NEXT = frozenset({"next", "follow", "afterwards", "afterward", "lead", "subsequently", "then"})
_WHERE = frozenset({"where", "keep", "store", "storage", "kept", "stored", "put", "place"})
_TOOL = frozenset({"tool", "utensil", "instrument", "implement", "device", "appliance"})
_ROUTINE = frozenset({"approach", "strategy", "routine", "sequence", "order", "procedure", "process", "workflow",
                      "steps", "step", "organize", "organise", "manage", "plan", "overall", "structure", "typically",
                      "start", "begin"})
_METHOD = frozenset({"method", "technique", "style", "way", "how", "choose", "choice", "prefer", "favor", "favour"})
HABIT_WINDOW = 30.0  # seconds: what follows an action must follow within this
CONTEXT_WINDOW = {"preference": 8.0, "routine": 25.0, "recall": 0.0}
NEXT_ACTIONS = 2  # actions after a trigger read as what followed it


@dataclass
class Intent:
    kind: str
    relation: str  # next | where | tool | method | order | what
    clauses: list[Clause]
    subject_nouns: list[str]
    subject_verbs: list[str]
    place: str | None
    videos: list[str]
    text: str  # the stem without the participant id or the instructions

    @property
    def trigger(self) -> Clause | None:
        return next((c for c in self.clauses if c.verb), None)

    def query(self) -> str:
        """Words to search memory with: the stem's action, objects and place."""
        return re.sub(r"\s+", " ", _PARTICIPANT.sub("", self.text)).strip(" ?.,")


@dataclass(frozen=True)
class Event:
    """One action in memory as classes, with the ids of the bank nodes it comes from."""

    video: str
    t: float
    verb: str | None
    nouns: tuple[str, ...]
    ids: tuple[str, ...] = ()
    weight: float = 1.0
    origin: str = "log"  # log | habit | storage | tool | routine | object
    follows: tuple[tuple[str | None, tuple[str, ...]], ...] = ()  # a habit: the actions that follow it
    text: str = ""  # the record's own words (a narration, a statement), for the semantic check
    claim: object = None  # a task-pattern record as a `claims.Claim` (how a task is done), checked against options
    word: str = ""  # the narrated verb word below its class ("lather" for *wash*), when one action was narrated


@dataclass
class ReaderDecision:
    letter: str  # A-D, or E
    reason: str  # "supported" | "no record of the subject" | "evidence does not separate the options"
    scores: list[float]
    support: list[list[str]]  # evidence ids behind each option's score
    intent: Intent
    events: int = 0
    features: dict[str, float] = field(default_factory=dict)  # the evidence features the calibration reads
    probability: float | None = None  # P(the answer given is right), when a calibration decided
    p_best: float | None = None  # P(the best option is right)
    p_e: float | None = None  # P(E is right: memory does not hold the answer)

    @property
    def abstained(self) -> bool:
        return self.letter == OPTION_E

    def text(self) -> str:
        s = ", ".join(f"{'ABCD'[i]}={x:.3f}" for i, x in enumerate(self.scores))
        conf = f"; P(right)={self.probability:.3f}" if self.probability is not None else ""
        return f"{self.intent.kind}/{self.intent.relation}: {s}; {self.reason}{conf}"


def stem_of(question: str) -> str:
    return question.split("\n\nIMPORTANT:")[0].strip()


def parse_question(question: str, lex: Lexicon) -> Intent:
    """The stem as an intent. The kind comes from what the question asks, not from item metadata:
    a video it names (recall), what follows an action (habit), an approach or sequence (routine),
    else a preference or method."""
    text = stem_of(question)
    videos = list(dict.fromkeys(_VIDEO.findall(text)))
    clauses = lex.parse(text)
    asked = set(lex.question_words(text))
    words = set(lex.lemmas(text))
    nouns = list(dict.fromkeys(n for c in clauses for n in c.nouns))
    nouns += [n for n in lex.question_nouns(text) if n not in nouns]
    verbs = list(dict.fromkeys(c.verb for c in clauses if c.verb))
    place = next((c.place for c in clauses if c.place), None)
    starts_after = text.lower().startswith(("after", "once"))
    if asked & {"where"} or (asked & _WHERE and not asked & _NEXT and "do" not in asked):
        relation = "where"
    elif asked & _NEXT or (starts_after and asked & {"do", "does", "what"} and not asked & _METHOD):
        relation = "next"
    elif words & _TOOL or asked & _TOOL:
        relation = "tool"
    elif words & {"order", "sequence", "first", "before", "steps"}:
        relation = "order"
    elif videos:
        relation = "what"
    else:
        relation = "method"
    if videos:
        kind = "recall"
    elif relation == "next":
        kind = "habit"
    elif words & _ROUTINE:
        kind = "routine"
    else:
        kind = "preference"
    return Intent(kind, relation, clauses, nouns, verbs, place, videos, text)


# -- options --------------------------------------------------------------------------------------

Item = tuple[str, str]  # ("v", verb class) | ("n", noun class) | ("w", a narrated verb word)
# An option's own verb word counts beside its class in a routine or method question, at this weight
# of a class item: "lathers the pan" and "rinses the pan" are both *wash*, and memory's narration
# says which. Chosen on P01-P03 (0.3 over 0.5 and 1: a paraphrase the narration never uses,
# "places" for "put", loses little).
VERB_WORD = 0.3


def option_items(option: str, intent: Intent, lex: Lexicon) -> tuple[list[list[Item]], set[Item]]:
    """Per non-negated clause, its items (verb, objects, place, instrument); and the items the
    option negates. The subject's own objects stay: weighted by how many options name them
    (`_weights`), they count only where they tell options apart ("on the bowl" vs "on the counter")."""
    clauses, negated = [], set()
    fine = intent.kind in ("routine", "preference")
    for c, word in zip(lex.parse(option), lex.verb_words(option) if fine else repeat(None)):
        items = ([("v", c.verb)] if c.verb else []) + [("n", n) for n in dict.fromkeys(c.nouns)]
        if word and not c.negated:  # a routine or method question: its own verb word too, below its class
            items.append(("w", word))
        if c.negated:
            negated.update(items)
        elif items:
            clauses.append(items)
    return clauses, negated


def _weights(per_option: list[list[list[Item]]]) -> dict[Item, float]:
    """An item's weight: how much it tells the options apart (1 for one option, 1/4 for all)."""
    df: dict[Item, int] = defaultdict(int)
    for clauses in per_option:
        for x in {x for c in clauses for x in c}:
            df[x] += 1
    return {x: (VERB_WORD if x[0] == "w" else 1.0) / n for x, n in df.items()}


# -- evidence -------------------------------------------------------------------------------------

def _items_of(e: Event) -> set[Item]:
    """An action's items: its verb class, its objects' classes and the narrated verb word."""
    out = ({("v", e.verb)} if e.verb else set()) | {("n", n) for n in e.nouns}
    if e.word:
        out.add(("w", e.word))
    return out


def _hit(x: Item, have: set[Item], verbs: set[str], lex: Lexicon) -> float:
    if x in have:
        return 1.0
    if x[0] == "v" and any(lex.same_category(x[1], v) for v in verbs):
        return 0.5
    return 0.0


def _match(items: list[Item], have: set[Item], w: dict[Item, float], lex: Lexicon) -> float:
    total = sum(w.get(x, 1.0) for x in items)
    if not total:
        return 0.0
    verbs = {v for k, v in have if k == "v"}
    return sum(w.get(x, 1.0) * _hit(x, have, verbs, lex) for x in items) / total


def _sequences(events: list[Event]) -> dict[str, list[Event]]:
    by_video: dict[str, list[Event]] = defaultdict(list)
    seen = set()
    for e in events:
        if e.origin != "log":
            continue
        key = (e.video, round(e.t, 2), e.verb, e.nouns)
        if key not in seen:
            seen.add(key)
            by_video[e.video].append(e)
    for seq in by_video.values():
        seq.sort(key=lambda e: e.t)
    return by_video


def _is_trigger(e: Event, trigger: Clause | None, nouns: set[str], lex: Lexicon, relax: int = 0) -> bool:
    verb = trigger.verb if trigger is not None and relax < 2 else None
    if verb and e.verb != verb and not (e.verb and lex.same_category(e.verb, verb)
                                        and (relax >= 1 or verb in ("put", "insert", "take", "lift"))):
        return False
    return not nouns or bool(nouns & set(e.nouns))


RELAX_LEVELS = 3  # 0: the trigger as asked; 1: any verb of its category; 2: any action on its objects


def habit_windows(intent: Intent, events: list[Event], lex: Lexicon,
                  relax: int = 0) -> list[tuple[set[Item], float, tuple[str, ...]]]:
    """What followed the question's trigger action: per occurrence in the activity log, the items
    of the next actions (within HABIT_WINDOW s); per consolidated habit with that trigger, its next
    step, weighted by how often it was counted. `relax` widens the trigger when memory never shows
    it as asked ("shifts a container" where memory says "moves" or "takes" it): 1 accepts any verb
    of the same category, 2 any action on the trigger's objects."""
    trigger = intent.trigger
    if trigger is None and relax < 2:
        return []
    nouns = set((trigger.objects() or trigger.nouns) if trigger else ()) or set(intent.subject_nouns)
    if relax >= 2 and not nouns:
        return []
    out = []
    for seq in _sequences(events).values():
        for i, e in enumerate(seq):
            if not _is_trigger(e, trigger, nouns, lex, relax):
                continue
            have: set[Item] = set()
            ids: list[str] = list(e.ids)
            n = 0
            for f in seq[i + 1:]:
                if f.t - e.t > HABIT_WINDOW:
                    break
                if (f.verb, f.nouns) == (e.verb, e.nouns):
                    continue
                have |= _items_of(f)
                ids += f.ids
                n += 1
                if n >= NEXT_ACTIONS:
                    break
            if have:
                out.append((have, 1.0, tuple(dict.fromkeys(ids))))
    for e in events:
        if e.origin == "habit" and e.follows and _is_trigger(e, trigger, nouns, lex, relax):
            have = set()
            for verb, ns in e.follows:
                have |= ({("v", verb)} if verb else set()) | {("n", n) for n in ns}
            out.append((have, e.weight, e.ids))
    return out


def context_windows(intent: Intent, events: list[Event], lex: Lexicon) -> list[tuple[set[Item], float, tuple[str, ...]]]:
    """The actions around the subject: for every logged action on one of its objects (in the named
    video, for recall), the items of the actions within the kind's window; every consolidated
    record about the subject (storage place, tool, routine steps) as one window, weighted by its
    count."""
    width = CONTEXT_WINDOW[intent.kind]
    subject = set(intent.subject_nouns)
    out = []
    for video, seq in _sequences(events).items():
        if intent.videos and video not in intent.videos:
            continue
        times = [f.t for f in seq]
        for e in seq:
            if subject and not (subject & set(e.nouns)):
                continue
            if intent.relation == "where" and (lex.verb_category.get(e.verb or "") != "leave" or not e.nouns
                                               or (subject and e.nouns[0] not in subject)):
                continue  # where it is kept: where it was put (it, not something put into it)
            have: set[Item] = set()
            ids: list[str] = []
            span = 0.0 if intent.relation == "where" else width
            for f in seq[bisect_left(times, e.t - span):bisect_right(times, e.t + span)]:
                have |= _items_of(f)
                ids += f.ids
            out.append((have, 1.0, tuple(dict.fromkeys(ids))))
    if not intent.videos:
        for e in events:
            if e.origin in ("storage", "tool", "routine", "habit") and (not subject or subject & set(e.nouns)):
                if intent.relation == "where" and not (e.origin == "storage" and e.verb and e.nouns
                                                       and (not subject or e.nouns[0] in subject)):
                    continue
                have = _items_of(e)
                for verb, ns in e.follows:
                    have |= ({("v", verb)} if verb else set()) | {("n", n) for n in ns}
                out.append((have, e.weight, e.ids))
    return out


def _specificity(events: list[Event], intent: Intent):
    """How little an item says because it is everywhere: 1 for an action or object rare in the
    retrieved memory, less for one most records share ("take", "put", "hand"). Computed over the
    logged actions outside the question's own video."""
    log = [e for e in events if e.origin == "log" and e.video not in intent.videos]
    if len(log) < 20:
        return lambda x: 1.0
    df: dict[Item, int] = defaultdict(int)
    for e in log:
        for x in _items_of(e):
            df[x] += 1
    n, floor = len(log), 0.01

    def spec(x: Item) -> float:
        p = df.get(x, 0) / n
        return math.log(1 + 1 / (p + floor)) / math.log(1 + 1 / floor)
    return spec


# -- scoring --------------------------------------------------------------------------------------

POWER = 2.0  # a window that matches the whole option counts more than two that match half of it
# Tuned on P01-P03 of the calibration cohort (P04 held out), for the highest accuracy over answerable
# questions and E-correct controls together; a margin rule (best barely ahead) lost more answerable
# items than it won controls, so only an exact tie counts as not separating the options.
MIN_SUPPORT = 2.2  # the best option's support (classes + SEMANTIC x cosine) below this: too weak to answer ...
CLASS_SURE = 0.8  # ... unless its actions and objects alone are supported this well (short options read weakly)


SEMANTIC = 3.0  # weight of the options' closeness in meaning to the evidence records, next to their classes
MAX_TEXTS = 80  # evidence records compared in meaning with the options


def _head(noun: str) -> str:
    return noun.split(":")[0]


def subject_mentions(subject: set[str], events: list[Event]) -> int:
    """How many evidence events name one of the subject's objects, at the class level or as a
    compound of the same head ("board:chopping" and "board"; "liquid:washing" and "liquid"): the
    memory's own classes and the question's may name one object at different depths."""
    if not subject:
        return 0
    heads = {_head(n) for n in subject}
    return sum(1 for e in events if subject & set(e.nouns) or heads & {_head(n) for n in e.nouns})


def situation_windows(intent: Intent, events: list[Event], lex: Lexicon):
    """The windows of the question's situation and how far the situation had to be widened to find
    any (0: as asked): a habit's trigger by `habit_windows`' levels; where something is kept, by
    the actions around it when memory never shows it put anywhere."""
    if intent.kind == "habit":
        for relax in range(RELAX_LEVELS):
            windows = habit_windows(intent, events, lex, relax)
            if windows:
                return windows, relax
        return [], RELAX_LEVELS
    windows = context_windows(intent, events, lex)
    if not windows and intent.relation == "where":
        windows = context_windows(replace(intent, relation="method"), events, lex)
        return windows, 1 if windows else RELAX_LEVELS
    return windows, 0 if windows else RELAX_LEVELS


def _at_memory_depth(intent: Intent, events: list[Event], lex: Lexicon) -> Intent:
    """The question's subject at the depth memory names it: where memory holds none of the
    subject's classes but holds a compound or head of one ("board" for "board:chopping",
    "board:chopping" for "board"), those classes become the subject (and the trigger's objects)."""
    subject = set(intent.subject_nouns)
    if not subject or any(subject & set(e.nouns) for e in events):
        return intent
    heads = {_head(n): n for n in intent.subject_nouns}
    # a subject that names its whole category ("utensil", "container", "cutlery") is any of its classes
    general = {lex.noun_category[n]: n for n in intent.subject_nouns
               if lex.noun_category.get(n, "").startswith(_head(n))}
    alias: dict[str, list[str]] = defaultdict(list)
    for e in events:
        for n in e.nouns:
            src = heads.get(_head(n)) or general.get(lex.noun_category.get(n, ""))
            if src and n not in alias[src]:
                alias[src].append(n)
    if not alias:
        return intent

    def swap(nouns: list[str]) -> list[str]:
        return list(dict.fromkeys(m for n in nouns for m in (alias.get(n) or [n])))

    clauses = [Clause(c.verb, swap(c.nouns), c.place, c.instrument, c.negated, list(c.words)) for c in intent.clauses]
    return Intent(intent.kind, intent.relation, clauses, swap(intent.subject_nouns), intent.subject_verbs,
                  intent.place, intent.videos, intent.text)


def score(question: str, choices: list[str], events: list[Event], lex: Lexicon, embed=None,
          calibration=None) -> ReaderDecision:
    """Score the options against the events and decide. `embed(texts) -> unit vectors` (optional)
    adds how close each option is in meaning to the evidence records the typed lookups selected:
    paraphrases the classes miss ("a squeeze of washing-up liquid" for "pour soap").
    `calibration` (`agent.confidence.Calibration`) turns the evidence features into the probability
    that the best option is right and decides E by a threshold on it; without one the fixed rules
    (MIN_SUPPORT, CLASS_SURE) decide and no probability is given."""
    intent = _at_memory_depth(parse_question(question, lex), events, lex)
    parsed = [option_items(c, intent, lex) for c in choices[:4]]
    w = _weights([p[0] for p in parsed])
    spec = _specificity(events, intent)
    w = {x: v * spec(x) for x, v in w.items()}
    windows, relaxed = situation_windows(intent, events, lex)
    subject = set(intent.subject_nouns)
    mentions = subject_mentions(subject, events)
    no_subject = bool(subject) and not mentions
    scores, support = [0.0] * 4, [[] for _ in range(4)]
    classes = list(scores)
    sims = [0.0] * 4
    if windows and not no_subject:
        scores, support = [], []
        for clauses, negated in parsed:
            if not clauses:
                scores.append(0.0)
                support.append([])
                continue
            if intent.kind == "recall":
                s, ids = _presence(clauses, windows, w, lex)
                if len(clauses) > 1:  # a sequence: the order the video holds them in counts too
                    a, aids = _aligned(clauses, _recall_sequence(intent, events), w, lex)
                    s, ids = 0.4 * s + 0.6 * a, aids or ids
            else:
                s, ids = _frequency(clauses, windows, w, lex)
            if negated:
                neg, _ = _frequency([sorted(negated)], windows, {x: 1.0 for x in negated}, lex)
                s *= max(0.0, 1.0 - neg)
            scores.append(s)
            support.append(ids)
        scores += [0.0] * (4 - len(scores))
        support += [[] for _ in range(4 - len(support))]
        classes = list(scores)
        if embed is not None and SEMANTIC:
            for i, sim in enumerate(_closeness(choices[:4], _context_texts(events, windows), embed)):
                if parsed[i][0] or sim:
                    sims[i] = sim
                    scores[i] += SEMANTIC * sim
    # how strongly memory supports an answer at all is read from the evidence as it stands ...
    read = sorted(range(len(scores)), key=lambda i: (-scores[i], i))
    feats = evidence_features(intent, events, windows, mentions, scores, classes, sims, read, support)
    if windows and not no_subject and intent.kind in ("routine", "preference") and claims_enabled():
        # ... the task-pattern records only decide which option that is
        scores, support = _reordered(scores, support, *task_claims(choices[:4], events, claim_subject(intent), lex))
    order = sorted(range(len(scores)), key=lambda i: (-scores[i], i))
    best, second = scores[order[0]], scores[order[1]] if len(order) > 1 else 0.0
    feats["rule_supported"] = float(best >= MIN_SUPPORT or classes[read[0]] >= CLASS_SURE)  # the fixed rule's cut
    for level in range(1, RELAX_LEVELS):
        feats[f"relaxed_{level}"] = float(relaxed == level)  # the situation had to be widened this far
    d = ReaderDecision(OPTION_E, "", scores, support, intent, len(events), features=feats)
    if calibration is not None:
        p = calibration.probabilities(feats)
        d.p_best, d.p_e = p["best"], p["E"]
        if no_subject:
            d.reason = "no record of the subject"
        elif not windows:
            d.reason = NO_SITUATION
        elif best == second:
            d.reason = "the evidence does not separate the options"
        elif p["best"] < calibration.threshold:
            d.reason = f"the evidence is too weak to support any option (P(best)={p['best']:.2f})"
        else:
            d.letter, d.reason = "ABCD"[order[0]], "supported"
        d.probability = d.p_best if d.letter != OPTION_E else d.p_e
        return d
    if no_subject:
        d.reason = "no record of the subject"
    elif not windows:
        d.reason = NO_SITUATION
    elif best < MIN_SUPPORT and classes[read[0]] < CLASS_SURE:
        d.reason = "the evidence is too weak to support any option"
    elif best == second:
        d.reason = "the evidence does not separate the options"
    else:
        d.letter, d.reason = "ABCD"[order[0]], "supported"
    return d


def _reordered(scores: list[float], support: list[list[str]], shifts: list[float], claim_ids: list[list[str]]):
    """The options ranked again with the task-pattern records' shifts, the scores they hold kept:
    the records decide which option the evidence supports most, not how strongly memory supports
    an answer at all (that, and so abstaining, stays with the evidence as read)."""
    if not any(shifts):
        return scores, support
    n = len(scores)
    moved = sorted(range(n), key=lambda i: (-(scores[i] + shifts[i]), i))
    levels = sorted(scores, reverse=True)
    out = [0.0] * n
    for rank, i in enumerate(moved):
        out[i] = levels[rank]
    return out, [list(dict.fromkeys(claim_ids[i] + support[i])) if shifts[i] > 0 else support[i] for i in range(n)]


def claim_subject(intent: Intent) -> set[str]:
    """The objects a question asks how the person handles: its clauses' objects, not the places or
    tools they name ("gathering tomatoes from the box" is about the tomatoes, not how boxes are
    carried); all its subject nouns when no clause names an object."""
    objects = {n for c in intent.clauses for n in c.objects()}
    return (objects & set(intent.subject_nouns)) or objects or set(intent.subject_nouns)


def task_claims(choices: list[str], events: list[Event], subject: set[str], lex: Lexicon):
    """How the task-pattern records among the events move each option (`agent.claims`)."""
    claims = list(dict.fromkeys(e.claim for e in events if e.claim is not None))
    if not claims:
        return [0.0] * len(choices), [[] for _ in choices]
    return adjust(choices, claims, subject, lex)


def _share_found(nouns: list[str], events: list[Event]) -> float:
    """The share of the question's objects (and places) some evidence event names (at head level)."""
    if not nouns:
        return 1.0
    have = {_head(n) for e in events for n in e.nouns}
    return sum(_head(n) in have for n in nouns) / len(nouns)


def evidence_features(intent: Intent, events: list[Event], windows, mentions: int, scores: list[float],
                      classes: list[float], sims: list[float], order: list[int],
                      support: list[list[str]]) -> dict[str, float]:
    """What the calibration reads: how much of the subject memory holds, how strongly and how
    clearly the best option is supported (in classes and in meaning), and the question's kind."""
    b, s = order[0], order[1]
    f = {
        "subject_found": 0.0 if intent.subject_nouns and not mentions else 1.0,
        "subject_share": _share_found(intent.subject_nouns, events),
        "log_mentions": math.log1p(mentions),
        "log_events": math.log1p(len(events)),
        "log_windows": math.log1p(len(windows)),
        "best": scores[b],
        "second": scores[s],
        "margin": scores[b] - scores[s],
        "log_support": math.log1p(len(support[b])),
        "best_class": classes[b],
        "class_margin": classes[b] - max(classes[i] for i in range(len(classes)) if i != b),
        "best_sim": sims[b],
        "sim_margin": sims[b] - max(sims[i] for i in range(len(sims)) if i != b),
        "consolidated": float(sum(1 for e in events if e.origin in ("habit", "storage", "tool", "routine")) > 0),
    }
    for k in KINDS:
        f[f"kind_{k}"] = float(intent.kind == k)
        f[f"margin_{k}"] = f["margin"] * f[f"kind_{k}"]  # how much a clear best option says differs by kind
    return f


def _context_texts(events: list[Event], windows) -> list[str]:
    """The words of the records the windows were built from (most supported first)."""
    ids = {i for _, _, wid in windows for i in wid}
    out = [e.text for e in events if e.text and e.origin != "pattern" and (set(e.ids) & ids)]
    return list(dict.fromkeys(out))[:MAX_TEXTS]


def _closeness(options: list[str], texts: list[str], embed) -> list[float]:
    """Per option, its best cosine to any of the texts (0 without texts)."""
    if not texts:
        return [0.0] * len(options)
    import numpy as np

    opts, ev = embed(list(options)), embed(texts)
    return [float(x) for x in np.max(np.asarray(opts) @ np.asarray(ev).T, axis=1)]


def _frequency(clauses: list[list[Item]], windows, w, lex) -> tuple[float, list[str]]:
    """How strongly, and how often, the option's actions occur in the windows (weighted)."""
    items = [x for c in clauses for x in c]
    total = sum(weight for _, weight, _ in windows) or 1.0
    acc, ids = 0.0, []
    for have, weight, wid in windows:
        m = _match(items, have, w, lex)
        if m > 0:
            acc += weight * m ** POWER
            if m >= 0.5:
                ids += wid
    return (acc / total) ** (1 / POWER), list(dict.fromkeys(ids))[:12]


ORDER_SPAN = 90.0  # seconds an option's sequence of actions may span in the video


def _recall_sequence(intent: Intent, events: list[Event]) -> list[Event]:
    """The named video's logged actions in time order (near the subject, when the question has one)."""
    seqs = _sequences(events)
    out = [e for v in intent.videos for e in seqs.get(v, [])]
    subject = set(intent.subject_nouns)
    if subject:
        near = [e.t for e in out if subject & set(e.nouns)]
        out = [e for e in out if any(abs(e.t - t) <= ORDER_SPAN / 2 for t in near)]
    return out[:400]


def _aligned(clauses: list[list[Item]], seq: list[Event], w, lex) -> tuple[float, list[str]]:
    """The best match of the option's actions to the video's actions in the option's order, within
    ORDER_SPAN seconds: dynamic programming over (clause, event)."""
    if not seq:
        return 0.0, []
    n = len(seq)
    have = [_items_of(e) for e in seq]
    m = [[_match(c, have[j], w, lex) for j in range(n)] for c in clauses]
    best = [row[:] for row in m]
    back: list[list[int]] = [[-1] * n for _ in clauses]
    for i in range(1, len(clauses)):
        for j in range(n):
            top, arg = -1.0, -1
            for jj in range(j):
                if seq[j].t - seq[jj].t <= ORDER_SPAN and best[i - 1][jj] > top:
                    top, arg = best[i - 1][jj], jj
            best[i][j] = m[i][j] + top if arg >= 0 else -1.0
            back[i][j] = arg
    last = max(range(n), key=lambda j: best[-1][j])
    total = best[-1][last]
    if total < 0:
        return 0.0, []
    ids, j = [], last
    for i in range(len(clauses) - 1, -1, -1):
        ids += seq[j].ids
        j = back[i][j]
        if j < 0 and i > 0:
            break
    return total / len(clauses), list(dict.fromkeys(ids))[:12]


def _presence(clauses: list[list[Item]], windows, w, lex) -> tuple[float, list[str]]:
    """Whether each of the option's actions is in the video, best match per action, averaged."""
    vals, ids = [], []
    for c in clauses:
        best, best_ids = 0.0, ()
        for have, _, wid in windows:
            m = _match(c, have, w, lex)
            if m > best:
                best, best_ids = m, wid
        vals.append(best)
        ids += best_ids
    return sum(vals) / len(vals), list(dict.fromkeys(ids))[:12]
