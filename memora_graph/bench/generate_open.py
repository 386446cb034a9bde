"""Open questions (no answer choices) generated from annotations, and their scoring by type.

One participant's `Behaviour` index gives the gold answers, so every item is checked against the
annotations, never against a memory bank:

- place_last   where the object was last put (the second, place-like noun of its last put row)
- place_usual  where the object is usually put (dominant place: >= 3 puts in >= 2 videos, 1.5x ahead)
- time_last / time_first   the video of the last / first time an action happened (>= 2 videos)
- count        how many annotated rows the action has (scored within max(1, 20%))
- yes / no     has P ever done X: an observed action, or a verb and object both observed, never together
- next         the dominant next action after a trigger (>= 4 triggers in >= 2 videos, share >= 0.3,
               >= 3 cases, 1.5x ahead of the runner-up), scored at verb + noun class
- absent       an object other participants use and this one never does, or another person
- general      general-knowledge questions, some about kitchens
(absent and general are right when the answer is "not in memory".)

Each kind has several wordings in three splits (`SPLITS`): `dev`, the ones the reader was
developed against; `heldout`, written with them and read only after the first scored run;
`fresh`, written after that run and read after the calibration run; `final`, written before
`fresh` was read and never read before the P04 run. A figure on `final` says how the parser does
on wording it was not tuned to. `score_item` scores an `OpenAnswer`.
"""

from __future__ import annotations

import random
from collections import Counter
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, Field

from memora_graph.bench.behaviour import PUT_VERB_KEYS, ActionClass, Behaviour, noun_text, participle, past, verb_phrase
from memora_graph.bench.generate_scoped import CELLS, SCOPED_KINDS, generate_scoped

BASE_KINDS = ("place_last", "place_usual", "time_last", "time_first", "count", "yes", "no", "next", "absent", "general")
OPEN_KINDS = BASE_KINDS + SCOPED_KINDS
PER_KIND = {"place_last": 6, "place_usual": 6, "time_last": 5, "time_first": 5, "count": 8, "yes": 6, "no": 5,
            "next": 8, "absent": 8, "general": 8}
COUNT_TOLERANCE = 0.2
# wordings: dev (the reader was developed against them), heldout (written with dev, scored, and
# read once after the first run), fresh (written after that run, read after the calibration run),
# final (written before fresh was read, never read before the P04 run)
SPLITS = ("dev", "heldout", "fresh", "final")

# {P} person, {o} object, {b} base verb, {p} past, {g} gerund, {s} present (3rd person), {n} past participle
TEMPLATES: dict[str, dict[str, list[str]]] = {
    "place_last": {
        "dev": ["Where did {P} last put the {o}?", "Where did {P} most recently leave the {o}?",
                "Where was the {o} put the last time {P} put it down?"],
        "heldout": ["The last time {P} put the {o} away, where did it go?",
                    "Where did the {o} end up after {P} last put it somewhere?",
                    "In which place did {P} put the {o} most recently?"],
        "fresh": [
            "Where has {P} most recently placed the {o}?",
            "Tell me where {P} put the {o} the last time.",
            "What was the last location {P} left the {o} at?",
        ],
        "final": [
            "{P} put the {o} somewhere most recently - where was that?",
            "Most recently, where did {P} set down the {o}?",
            "Where was the {o} left by {P} the final time they put it down?",
        ],
    },
    "place_usual": {
        "dev": ["Where does {P} usually keep the {o}?", "Where does {P} typically put the {o}?",
                "Where is the {o} usually stored by {P}?"],
        "heldout": ["Which place does {P} normally put the {o} in?", "When {P} puts the {o} away, where does it usually go?",
                    "In what spot does {P} tend to leave the {o}?"],
        "fresh": [
            "Where would I normally find the {o} in {P}'s kitchen?",
            "Where does the {o} usually go when {P} is done with it?",
            "What is {P}'s usual spot for the {o}?",
        ],
        "final": [
            "Where does {P} generally put the {o} away?",
            "If I were looking for the {o} in {P}'s kitchen, where would it usually be kept?",
            "Where is {P}'s {o} normally stored?",
        ],
    },
    "time_last": {
        "dev": ["In which video did {P} last {b} the {o}?", "When did {P} most recently {b} the {o}?",
                "Which recording shows {P} {g} the {o} for the last time?"],
        "heldout": ["What was the last video in which {P} {p} the {o}?", "When was the latest time {P} {p} the {o}?",
                    "In what session did {P} {b} the {o} most recently?"],
        "fresh": [
            "Which video is the most recent one where {P} {p} the {o}?",
            "Tell me the last recording in which {P} {p} the {o}.",
            "When was the {o} last {n} by {P}?",
        ],
        "final": [
            "In which video was the {o} most recently {n} by {P}?",
            "What is the latest recording of {P} {g} the {o}?",
            "When was the final time {P} {p} the {o}? Name the video.",
        ],
    },
    "time_first": {
        "dev": ["In which video did {P} first {b} the {o}?", "When did {P} {b} the {o} for the first time?",
                "Which recording shows {P} {g} the {o} for the first time?"],
        "heldout": ["What was the earliest video in which {P} {p} the {o}?", "When was the first time {P} {p} the {o}?",
                    "In what session did {P} first {b} the {o}?"],
        "fresh": [
            "Which video shows the earliest time {P} {p} the {o}?",
            "Tell me the first recording where {P} {p} the {o}.",
            "When did {P} start to {b} the {o} - which video was the first?",
        ],
        "final": [
            "In which video was the {o} first {n} by {P}?",
            "What is the earliest recording of {P} {g} the {o}?",
            "When did {P} {b} the {o} for the very first time? Name the video.",
        ],
    },
    "count": {
        "dev": ["How many times did {P} {b} the {o}?", "How often did {P} {b} the {o} across all videos?",
                "Count the times {P} {p} the {o}."],
        "heldout": ["What is the number of times {P} {p} the {o}?", "How many times in total has {P} {n} the {o}?",
                    "On how many occasions did {P} {b} the {o}?"],
        "fresh": [
            "How many times has {P} {n} the {o} in total?",
            "Give the number of times {P} {p} the {o}.",
            "How frequently did {P} {b} the {o}? Give a count.",
        ],
        "final": [
            "Across all of {P}'s videos, how many times was the {o} {n}?",
            "What's the total count of {P} {g} the {o}?",
            "How many separate times did {P} {b} the {o}?",
        ],
    },
    "yes": {
        "dev": ["Has {P} ever {n} the {o}?", "Did {P} ever {b} the {o}?", "Does {P} {b} the {o}?"],
        "heldout": ["Is there any record of {P} {g} the {o}?", "Was {P} ever seen {g} the {o}?",
                    "Can memory show {P} {g} the {o}?"],
        "fresh": [
            "Have you ever seen {P} {b} the {o}?",
            "Did {P} {b} the {o} at any point?",
            "Has the {o} ever been {n} by {P}?",
        ],
        "final": [
            "Has {P} {n} the {o} before?",
            "Is it true that {P} {p} the {o} at some point?",
            "Do {P}'s videos show them {g} the {o}?",
        ],
    },
    "next": {
        "dev": ["What does {P} usually do after {g} the {o}?", "After {P} {s} the {o}, what do they typically do next?",
                "What does {P} tend to do right after they {b} the {o}?"],
        "heldout": ["Once {P} has {n} the {o}, what usually follows?", "What is {P}'s usual next action after {g} the {o}?",
                    "Right after {g} the {o}, what does {P} normally do?"],
        "fresh": [
            "Following {g} the {o}, what is {P}'s next move usually?",
            "What usually comes next after {P} {p} the {o}?",
            "Typically, what does {P} do immediately after they {b} the {o}?",
        ],
        "final": [
            "Whenever {P} {s} the {o}, what is the usual next thing they do?",
            "What's the most common action by {P} right after {g} the {o}?",
            "{P} has just {n} the {o}. What will they most likely do next?",
        ],
    },
    "absent": {
        "dev": ["Where does {P} keep the {o}?", "How many times did {P} use the {o}?", "Has {P} ever used a {o}?"],
        "heldout": ["When did {P} last touch the {o}?", "Is there any record of {P} handling the {o}?",
                    "What does {P} usually do with the {o}?"],
        "fresh": [
            "Where did {P} last leave the {o}?",
            "How often does {P} use the {o}?",
            "Did {P} ever pick up the {o}?",
        ],
        "final": [
            "Where did {P} put the {o} the last time?",
            "Has {P} ever {n} the {o}?",
            "How many times has {P} picked up the {o}?",
        ],
    },
}
TEMPLATES["no"] = TEMPLATES["yes"]
OTHER_PERSON = {"dev": ["Where did {Q} last put the {o}?"], "heldout": ["How many times did {Q} {b} the {o}?"],
                "fresh": ["Has {Q} ever {n} the {o}?"], "final": ["When did {Q} last {b} the {o}?"]}
GENERAL = {
    "dev": ["What is the capital of France?", "How many legs does a spider have?", "At what temperature does water boil?",
            "Who wrote Romeo and Juliet?", "What is the boiling point of water?", "Is a tomato a fruit?",
            "How many grams are in a kilogram?", "Which country does pasta come from?", "Why do onions make people cry?",
            "What is the chemical formula of salt?", "Where do bananas grow?", "How is cheese made?"],
    "heldout": ["Who invented the microwave oven?", "What is the tallest mountain in the world?",
                "How many teaspoons are in a tablespoon?", "Which vitamin is found in oranges?",
                "Where does coffee originally come from?", "What is the largest ocean on Earth?",
                "How long should an egg be boiled to be hard?", "Is olive oil healthier than butter?",
                "What year did the first person land on the moon?", "Which planet is closest to the sun?",
                "What is the main ingredient of guacamole?", "How many minutes are in a day?"],
    "fresh": ["What is the speed of light?", "Who painted the Mona Lisa?", "How many eggs are in a dozen?",
              "Where is the Eiffel Tower?", "When was the telephone invented?", "Which fruit is used to make wine?",
              "How hot does an oven get?", "Does bread contain gluten?", "What colour is a ripe banana?",
              "How many cups of flour go in a cake?", "Which metal is a frying pan usually made of?",
              "What does a whisk do?"],
    "final": ["How many continents are there?", "Who discovered penicillin?", "What is the freezing point of water in "
              "Fahrenheit?", "Which animal produces milk for most cheese?", "Where is the Great Wall?",
              "How many calories are in an apple?", "Is a cucumber a vegetable or a fruit?",
              "What language is spoken in Brazil?", "When did the Second World War end?",
              "Why does bread go stale?", "What is the capital city of Japan?", "How do you make mayonnaise?"],
}


class OpenItem(BaseModel):
    """One open question with its gold answer from the annotations."""

    question_id: str
    participant_id: str
    kind: str = Field(description="One of " + ", ".join(OPEN_KINDS))
    question: str
    template: str
    split: str = Field(description="dev, heldout, fresh or final (see SPLITS); scoped kinds: third or me (the "
                                   "wording's person)")
    gold: dict[str, Any]
    evidence: dict[str, Any] = Field(default_factory=dict)


@dataclass
class _Ctx:
    pid: str
    b: Behaviour
    rng: random.Random
    split: str | None  # only this split's templates (None: both)


def _fill(template: str, pid: str, action: ActionClass | None = None, noun: str = "", other: str = "") -> str:
    v = action.verb if action else "take"
    o = noun_text(noun or (action.noun if action else ""))
    return template.format(P=pid, Q=other, o=o, b=verb_phrase(v, "base"), p=past(v), g=verb_phrase(v, "gerund"),
                           s=verb_phrase(v, "present"), n=participle(v))


def _template(ctx: _Ctx, kind: str, pool: dict[str, list[str]] | None = None) -> tuple[str, str, str]:
    pool = pool or TEMPLATES[kind]
    splits = [ctx.split] if ctx.split else list(SPLITS)
    choices = [(s, i, t) for s in splits for i, t in enumerate(pool[s])]
    s, i, t = ctx.rng.choice(choices)
    return t, f"{kind}/{s}/{i}", s


def _steps(b: Behaviour):
    for video in b.videos:
        yield from b.steps_by_video[video]


def _phrasable(a: ActionClass) -> bool:
    return a.phrasable and a.noun not in ("hand", "") and a.verb not in ("let-go",)


def generate_open(b: Behaviour, others: dict[str, Behaviour], seed: int = 42, split: str | None = None,
                  per_kind: dict[str, int] | None = None, scoped: bool = True) -> list[OpenItem]:
    """Open questions for one participant (see the module docstring); `others` are the rest of
    the cohort (absent objects come from what they use)."""
    per_kind = per_kind or PER_KIND
    ctx = _Ctx(b.participant_id, b, random.Random(f"{seed}:{b.participant_id}:open"), split)
    items: list[OpenItem] = []
    steps = list(_steps(b))

    def add(kind: str, question: str, template: str, sp: str, gold: dict, evidence: dict | None = None):
        items.append(OpenItem(question_id=f"{b.participant_id}_open_{len(items):03d}", participant_id=b.participant_id,
                              kind=kind, question=question, template=template, split=sp, gold=gold,
                              evidence=evidence or {}))

    # where last put / usually kept
    puts: dict[str, list] = {}
    for s in steps:
        if s.place and s.action.verb in PUT_VERB_KEYS and s.place != s.action.noun and s.action.noun != "hand":
            puts.setdefault(s.action.noun, []).append(s)
    nouns = sorted(puts)
    for noun in ctx.rng.sample(nouns, min(per_kind["place_last"], len(nouns))):
        last = puts[noun][-1]
        t, tid, sp = _template(ctx, "place_last")
        add("place_last", _fill(t, b.participant_id, noun=noun), tid, sp, {"place": last.place},
            {"video": last.video_id, "time": last.start_s, "narration_id": last.narration_id})
    usual = []
    for noun, ss in puts.items():
        c = Counter(s.place for s in ss)
        (best, n), *rest = c.most_common()
        videos = {s.video_id for s in ss if s.place == best}
        if n >= 3 and len(videos) >= 2 and (not rest or n >= 1.5 * rest[0][1]):
            usual.append((noun, best, n, len(ss)))
    for noun, best, n, total in ctx.rng.sample(sorted(usual), min(per_kind["place_usual"], len(usual))):
        t, tid, sp = _template(ctx, "place_usual")
        add("place_usual", _fill(t, b.participant_id, noun=noun), tid, sp, {"place": best}, {"count": n, "of": total})

    # when / which video, how many, has P ever
    by_action: dict[ActionClass, list] = {}
    for s in steps:
        by_action.setdefault(s.action, []).append(s)
    multi = sorted(a for a, ss in by_action.items() if _phrasable(a) and len({s.video_id for s in ss}) >= 2)
    for kind in ("time_last", "time_first"):
        for a in ctx.rng.sample(multi, min(per_kind[kind], len(multi))):
            ss = by_action[a]
            s = ss[-1] if kind == "time_last" else ss[0]
            t, tid, sp = _template(ctx, kind)
            add(kind, _fill(t, b.participant_id, a), tid, sp, {"video": s.video_id},
                {"time": s.start_s, "narration_id": s.narration_id})
    countable = sorted(a for a, ss in by_action.items() if _phrasable(a) and len(ss) >= 2)
    for a in ctx.rng.sample(countable, min(per_kind["count"], len(countable))):
        t, tid, sp = _template(ctx, "count")
        add("count", _fill(t, b.participant_id, a), tid, sp, {"count": len(by_action[a])})
    seen = sorted(a for a in by_action if _phrasable(a))
    for a in ctx.rng.sample(seen, min(per_kind["yes"], len(seen))):
        t, tid, sp = _template(ctx, "yes")
        add("yes", _fill(t, b.participant_id, a), tid, sp, {"yes": True}, {"count": len(by_action[a])})
    verbs = Counter(a.verb for a in by_action)
    objects = Counter(a.noun for a in by_action)
    pairs = {(a.verb, a.noun) for a in by_action}
    put_nouns = {a.noun for a in by_action if a.verb in PUT_VERB_KEYS}
    never = sorted({ActionClass(v, n) for v in verbs for n in objects
                    if (v, n) not in pairs and verbs[v] >= 3 and objects[n] >= 3 and v not in PUT_VERB_KEYS
                    and v not in ("take", "move", "hold", "use") and _phrasable(ActionClass(v, n))
                    and not (v in PUT_VERB_KEYS and n in put_nouns)})
    for a in ctx.rng.sample(never, min(per_kind["no"], len(never))):
        t, tid, sp = _template(ctx, "no")
        add("no", _fill(t, b.participant_id, a), tid, sp, {"yes": False})

    # what next
    nexts = []
    for chain, table in b.chain_next.items():
        if len(chain) != 1 or not _phrasable(chain[0]):
            continue
        trig = b.action_evidence[chain[0]]
        total = sum(e.count for e in table.values())
        ranked = sorted(table.items(), key=lambda kv: (-kv[1].count, kv[0]))
        (nxt, ev), *rest = ranked
        if trig.count >= 4 and len(trig.videos) >= 2 and ev.count >= 3 and ev.count / total >= 0.3 \
                and (not rest or ev.count >= 1.5 * rest[0][1].count) and nxt.noun != "" and nxt != chain[0]:
            nexts.append((chain[0], nxt, ev.count, total))
    for trig, nxt, n, total in ctx.rng.sample(sorted(nexts), min(per_kind["next"], len(nexts))):
        t, tid, sp = _template(ctx, "next")
        add("next", _fill(t, b.participant_id, trig), tid, sp, {"verb": nxt.verb, "noun": nxt.noun},
            {"count": n, "of": total})

    # not in memory: objects others use and this person never does, another person, general knowledge
    mine = set(b.noun_evidence) | {n for d in b.places.values() for n in d} | {t for d in b.tools.values() for t in d}
    for s in steps:
        mine.add(s.action.noun)
    theirs = Counter()
    for o in others.values():
        for n, ev in o.noun_evidence.items():
            theirs[n] += ev.count
    # and whose name is no word of this person's narrations ("cloth" is narrated under another class)
    said = {w for s in steps for w in _lemmas(s.narration)}
    absent = sorted(n for n, c in theirs.items() if n not in mine and c >= 3 and n != "hand" and ":" not in n
                    and not set(_lemmas(noun_text(n))) & said)
    k = per_kind["absent"]
    picks = ctx.rng.sample(absent, min(k - k // 4, len(absent)))
    for noun in picks:
        t, tid, sp = _template(ctx, "absent")
        add("absent", _fill(t, b.participant_id, noun=noun), tid, sp, {"not_in_memory": "absent_subject"})
    other_ids = sorted(others)
    for _ in range(k // 4):
        if not other_ids or not seen:
            break
        a = ctx.rng.choice(seen)
        t, tid, sp = _template(ctx, "absent", OTHER_PERSON)
        add("absent", _fill(t, b.participant_id, a, other=ctx.rng.choice(other_ids)), tid, sp,
            {"not_in_memory": "absent_subject"}, {"other_person": True})
    pool = [(s, i, q) for s in ([split] if split else list(SPLITS)) for i, q in enumerate(GENERAL[s])]
    for s, i, q in ctx.rng.sample(pool, min(per_kind["general"], len(pool))):
        add("general", q, f"general/{s}/{i}", s, {"not_in_memory": "general_knowledge"})
    if scoped:  # scope x selector x relation kinds (generate_scoped), from a generator of their own
        generate_scoped(b, add, random.Random(f"{seed}:{b.participant_id}:scoped"), _fill, tag=str(seed))
    return items


def _lex():
    from memora_graph.perceive.lexicon import Lexicon

    return Lexicon.load()


def _lemmas(text: str) -> list[str]:
    return [w for w in _lex().lemmas(text) if w.isalpha()]


def _verbs(verb: str) -> set[str]:
    """A gold verb class and the class its words read as (EPIC's 'set' reads as 'put')."""
    return {verb, _lex().verb(verb) or verb}


def _nouns(noun: str) -> set[str]:
    """A gold noun class and the class its words read as ('wrap:plastic' is worded 'plastic wrap',
    which EPIC also lists under 'package')."""
    return {noun, *(_lex().noun_classes(noun_text(noun))[:1])}


def count_ok(pred: int | None, gold: int) -> bool:
    return pred is not None and abs(pred - gold) <= max(1, round(COUNT_TOLERANCE * gold))


def score_item(item: OpenItem, answer) -> dict[str, Any]:
    """Is `answer` (an OpenAnswer) right for `item`, by the item's type; and, for not-in-memory
    items, is the reason right."""
    g = item.gold
    ok = False
    if "not_in_memory" in g:
        ok = not answer.in_memory
    elif "place" in g:
        ok = answer.place is not None and answer.place.place == g["place"]
    elif "video" in g:
        ok = answer.moment is not None and answer.moment.video == g["video"]
    elif "count" in g:
        ok = count_ok(answer.count, int(g["count"]))
    elif "yes" in g:
        ok = answer.yes is not None and answer.yes == g["yes"]
    elif "verb" in g:
        ok = bool(answer.actions) and answer.actions[0].verb in _verbs(g["verb"]) and \
            answer.actions[0].noun in _nouns(g["noun"])
    reason_ok = None if "not_in_memory" not in g else (answer.reason == g["not_in_memory"])
    return {"correct": bool(ok), "reason_ok": reason_ok}


def generate_open_items(participants: list[str] | None, seed: int | list[int] = 42, annotations=None,
                        split: str | None = None) -> dict[str, list[OpenItem]]:
    """Open questions for each participant of the annotations (default: the bundled subset); with
    several seeds, the union of their questions (each question once)."""
    from memora_graph.bench.behaviour import build_behaviours
    from memora_graph.errors import DataError
    from memora_graph.perceive.annotations import load_annotations

    frame = load_annotations(annotations) if annotations is not None else load_annotations()
    behaviours = build_behaviours(frame)
    wanted = participants or sorted(behaviours)
    missing = [p for p in wanted if p not in behaviours]
    if missing:
        raise DataError(f"no annotations for {', '.join(missing)} (have: {', '.join(sorted(behaviours))})")
    seeds = [seed] if isinstance(seed, int) else list(seed)
    out: dict[str, list[OpenItem]] = {}
    for pid in wanted:
        others = {k: v for k, v in behaviours.items() if k != pid}
        seen: dict[str, OpenItem] = {}
        for sd in seeds:
            for it in generate_open(behaviours[pid], others, sd, split):
                seen.setdefault(it.question, it)
        out[pid] = [it.model_copy(update={"question_id": f"{pid}_open_{i:03d}"}) for i, it in enumerate(seen.values())]
    return out


def generate_open_files(out, participants: list[str] | None, seed: int = 42, annotations=None) -> dict[str, dict]:
    """Write OUT/open/pXX.json per participant; the counts per kind."""
    from pathlib import Path

    from memora_graph.bench.tasks import write_json

    items = generate_open_items(participants, seed, annotations)
    counts = {}
    for pid, its in items.items():
        write_json(Path(out) / "open" / f"{pid.lower()}.json",
                   {"participant_id": pid, "seed": seed, "questions": [i.model_dump() for i in its]})
        c = Counter(i.kind for i in its)
        counts[pid] = {k: c.get(k, 0) for k in OPEN_KINDS} | {"total": len(its)}
    return counts
