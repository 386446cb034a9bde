"""The MEMORA-Bench metric panel, as pure functions (paper definitions; METHOD_NOTES 1-2).

EAM-QA: answer-letter parsing, accuracy, E-selection rate, per-type accuracy, and the three
evaluation views (full; MEMORA-committed; parametric-missed + MEMORA-committed), pooled over
items and macro-averaged over participants.

Planning: the plan parser; Exec; OrderExec (LCS over normalized verbs by default, the reference
implementation's greedy prefix as an option); KeyObj; PrefAdh; RGP (mean of the condition-level
means of OrderExec, KeyObj, PrefAdh, undefined values skipped); KBGround; ObjGT-R/P/F1; GR/GP/GF1.
Undefined values are None and are skipped by the aggregates.
"""

from __future__ import annotations

import re
from collections import defaultdict
from statistics import mean
from typing import Any, Iterable, Literal

from memora_graph.sequences import lcs_length

# =============================================================================================
# EAM-QA
# =============================================================================================

CONTENT_LETTERS = frozenset("ABCD")
_ANSWER_MARKER = re.compile(
    r"(?i:final\s+answer|answer|correct\s+option|option|choice)\s*(?:is\b)?\s*[:=\-]?\s*[*_`\"'(\[]*\s*([A-Ea-e])(?![A-Za-z0-9])"
)
_ONLY_LETTER = re.compile(r"^\W*([A-E])\W*$")
_LINE_LETTER = re.compile(r"^\s*[*_`]*\(?([A-E])[).:\]]\s", re.M)
_BOLD_LETTER = re.compile(r"\*\*\(?([A-E])\)?\*\*")
_PAREN_LETTER = re.compile(r"\b([A-E])\)")
_STANDALONE = re.compile(r"\b([A-E])\b")


def parse_answer_letter(text: str | None, choices: list[str] | None = None) -> str:
    """The chosen letter A-E, or "" when none can be read.

    In order: the last explicit marker ("Answer: C", "final answer is **D**", "Option E" -- a
    final "Answer: C" with nothing after it counts); a reply that is only a letter; a single
    distinct letter opening a line ("B) ...", "(B) ...", "B. ..."); a single bold letter; a single
    distinct "X)"; the first standalone capital letter that is not the article "A" (an "A"
    followed by a lowercase word is read as the article); finally the one option whose text
    appears in the reply.
    """
    if not text:
        return ""
    text = re.sub(r"<think>.*?</think>", " ", text, flags=re.S).strip()
    markers = _ANSWER_MARKER.findall(text)
    if markers:
        return markers[-1].upper()
    m = _ONLY_LETTER.match(text)
    if m:
        return m.group(1)
    for pattern in (_LINE_LETTER, _BOLD_LETTER, _PAREN_LETTER):
        found = set(pattern.findall(text))
        if len(found) == 1:
            return found.pop()
    for m in _STANDALONE.finditer(text):
        letter = m.group(1)
        if letter == "A" and re.match(r"\s+[a-z]", text[m.end():]):
            continue
        return letter
    if choices:
        low = text.lower()
        hits = [i for i, c in enumerate(choices[:5])
                if len(c.strip(" .")) > 1 and re.search(r"\b" + re.escape(c.lower().strip(" .")) + r"\b", low)]
        if len(hits) == 1:
            return "ABCDE"[hits[0]]
    return ""


def _pred(record: dict) -> str:
    return (record.get("predicted", record.get("predicted_answer")) or "").strip().upper()


def eam_scores(records: Iterable[dict]) -> dict[str, Any]:
    """Accuracy, E-selection rate, and both per type.

    Each record: {question_id, qa_type, correct_answer, predicted} ("predicted_answer" is
    accepted too; a question that failed is scored with predicted "").
    """
    records = list(records)
    n = len(records)
    correct = sum(_pred(r) == r["correct_answer"] for r in records)
    chose_e = sum(_pred(r) == "E" for r in records)
    by_type: dict[str, list[dict]] = defaultdict(list)
    for r in records:
        by_type[r.get("qa_type", "")].append(r)
    return {
        "n": n,
        "correct": correct,
        "accuracy": correct / n if n else None,
        "e_rate": chose_e / n if n else None,
        "per_type_n": {t: len(rs) for t, rs in sorted(by_type.items())},
        "per_type_accuracy": {t: sum(_pred(r) == r["correct_answer"] for r in rs) / len(rs) for t, rs in sorted(by_type.items())},
        "per_type_e_rate": {t: sum(_pred(r) == "E" for r in rs) / len(rs) for t, rs in sorted(by_type.items())},
        "failed_questions": sorted(r["question_id"] for r in records if _pred(r) == ""),
    }


VIEWS = ("full", "memora_committed", "parametric_missed_memora_committed")


def eam_views(
    results: dict[str, dict[str, list[dict]]],
    memora: str = "memora_full",
    parametric: str = "no_memory",
    baselines: list[str] | None = None,
) -> dict[str, Any]:
    """The paper's three EAM-QA views, pooled (item-weighted) and macro-averaged over participants.

    `results[condition][participant]` is that condition's list of records (see eam_scores).
    Within each participant every condition is scored on the same ids: the ids all conditions
    answered (full); of those, the ids where `memora` chose A-D (MEMORA-committed); of those,
    the ids where `parametric` was wrong (parametric-missed + MEMORA-committed). Baselines for
    delta_pp default to every condition except memora, memora_episodic and parametric.
    Also reports the commit rate P(memora A-D | parametric wrong), pooled.
    """
    if memora not in results:
        raise ValueError(f"no results for the MEMORA condition {memora!r}; have {sorted(results)}")
    conditions = sorted(results)
    if baselines is None:
        baselines = [c for c in conditions if c not in (memora, "memora_episodic", parametric)]
    participants = sorted(set().union(*(results[c].keys() for c in conditions)))
    index = {c: {p: {r["question_id"]: r for r in results[c].get(p, [])} for p in participants} for c in conditions}
    eligible: dict[str, dict[str, set[str]]] = {v: {} for v in VIEWS}
    missed_total = committed_missed = 0
    for p in participants:
        common = set.intersection(*(set(index[c][p]) for c in conditions))
        committed = {q for q in common if _pred(index[memora][p][q]) in CONTENT_LETTERS}
        eligible["full"][p] = common
        eligible["memora_committed"][p] = committed
        if parametric in results:
            missed = {q for q in common if _pred(index[parametric][p][q]) != index[parametric][p][q]["correct_answer"]}
            eligible["parametric_missed_memora_committed"][p] = committed & missed
            missed_total += len(missed)
            committed_missed += len(committed & missed)
    out: dict[str, Any] = {}
    for view in VIEWS:
        if view == "parametric_missed_memora_committed" and parametric not in results:
            continue
        per_condition = {}
        for c in conditions:
            per_p = {}
            for p in participants:
                ids = eligible[view][p]
                right = sum(_pred(index[c][p][q]) == index[c][p][q]["correct_answer"] for q in ids)
                per_p[p] = {"correct": right, "total": len(ids), "accuracy": right / len(ids) if ids else None}
            total = sum(v["total"] for v in per_p.values())
            right = sum(v["correct"] for v in per_p.values())
            accs = [v["accuracy"] for v in per_p.values() if v["accuracy"] is not None]
            per_condition[c] = {
                "n": total, "pooled": right / total if total else None,
                "macro": mean(accs) if accs else None, "per_participant": per_p,
            }
        scored = [(per_condition[b]["pooled"], b) for b in baselines if per_condition.get(b, {}).get("pooled") is not None]
        best = max(scored) if scored else (None, None)
        mem = per_condition[memora]["pooled"]
        out[view] = {
            "conditions": per_condition, "best_baseline": best[1],
            "delta_pp": 100 * (mem - best[0]) if mem is not None and best[0] is not None else None,
        }
    out["commit_rate"] = committed_missed / missed_total if missed_total else None
    return out


# =============================================================================================
# Planning: plan parsing
# =============================================================================================

MAX_PLAN_STEPS = 15
_STRIP = [
    re.compile(r"<tool_call>.*?</tool_call>", re.S | re.I),
    re.compile(r"<tool_response>.*?</tool_response>", re.S | re.I),
    re.compile(r"\{\"query\":.*?\}\}", re.S),
]
_NUMBERED = re.compile(r"^\s*\d+[.)]\s*(.+?)\s*$")
_NUMBERED_STRICT = re.compile(r"^\s*\d+[.)]\s+(.+?)\s*$")
_BULLET = re.compile(r"^\s*[-*]\s+(.+?)\s*$")


def _dedup_cap(steps: list[str]) -> list[str]:
    out: list[str] = []
    for s in steps:
        if not out or out[-1].lower() != s.lower():
            out.append(s)
    return out[:MAX_PLAN_STEPS]


def extract_plan(text: str | None) -> list[str]:
    """Plan steps from a model reply (METHOD_NOTES 1.1): a numbered block after "Plan:" (the last
    such block wins), else >= 2 numbered lines, else >= 2 bullets; consecutive duplicates
    dropped; at most 15 steps."""
    if not text:
        return []
    for pattern in _STRIP:
        text = pattern.sub(" ", text)
    lines = text.splitlines()
    heads = [i for i, line in enumerate(lines) if re.search(r"plan\s*:", line, re.I)]
    for h in reversed(heads):
        items: list[str] = []
        for line in lines[h + 1:]:
            m = _NUMBERED.match(line)
            if m:
                items.append(m.group(1))
            elif line.strip() and items:
                break
            elif line.strip() and not items:
                break
        if items:
            return _dedup_cap(items)
    numbered = [m.group(1) for line in lines if (m := _NUMBERED_STRICT.match(line))]
    if len(numbered) >= 2:
        return _dedup_cap(numbered)
    bullets = [m.group(1) for line in lines if (m := _BULLET.match(line))]
    if len(bullets) >= 2:
        return _dedup_cap(bullets)
    return []


def plan_from_result(result: dict) -> list[str]:
    """The scored plan of a result record: generated_plan, else plan_steps; a string is split into lines."""
    plan = result.get("generated_plan")
    if plan is None or plan == [] or plan == "":
        plan = result.get("plan_steps")
    if plan is None:
        return []
    if isinstance(plan, str):
        return [line.strip() for line in plan.splitlines() if line.strip()]
    return [str(s).strip() for s in plan if str(s).strip()]


# =============================================================================================
# Planning: Exec predicates (METHOD_NOTES 1.2)
# =============================================================================================

ACTION_VERBS = (
    "pick up", "put down", "open", "close", "wash", "pour", "cut", "turn on", "turn off", "place", "move", "take",
    "grab", "rinse", "dry", "wipe", "slice", "chop", "peel", "stir", "mix", "squeeze", "fill", "empty", "flip",
    "scoop", "spread", "throw", "shake", "scrub", "adjust", "pull", "push", "set", "remove", "add", "press", "lift",
    "lower", "fold", "unfold", "heat", "boil", "fry", "bake", "toast", "grate", "crack", "whisk", "measure",
    "transfer", "serve", "bring", "carry", "reach", "reach for", "grasp", "hold", "grip", "release", "position",
    "continue", "approach", "locate", "identify", "prepare", "ensure", "gather", "collect", "arrange", "toss",
    "dispose", "discard", "rotate", "check", "inspect", "retrieve", "return", "stack", "pick_up", "reach_for",
    "picks up", "places", "holding", "scrubbing", "rinsing", "wiping", "peeling", "stirring", "cutting",
)
LOCATION_NOUNS = (
    "counter", "countertop", "cabinet", "sink", "shelf", "drawer", "fridge", "refrigerator", "stove", "oven",
    "table", "rack", "drying rack", "dish rack", "worktop", "pan", "pot", "board", "cutting board",
    "chopping board", "microwave", "dishwasher", "bin", "trash", "garbage", "hob", "burner", "plate rack",
    "sink area", "sink_area", "counter area", "countertop_area", "left zone", "right zone", "center zone",
    "table_area", "drying_rack_area", "left_zone", "right_zone", "center_zone", "colander", "bowl", "plate", "tap",
    "faucet",
)
LOCATION_PREPOSITIONS = (
    "on", "in", "from", "near", "next to", "under", "above", "inside", "at", "behind", "beside", "between", "onto",
    "into", "out of", "toward", "towards", "across",
)
_OBJECT_STOPWORDS = frozenset({"the", "a", "an", "and", "or", "then", "to", "with", "for", "is", "are"})
_PRONOUN_ONLY = frozenset({"it", "the thing", "that", "this", "them", "those", "these", "something", "stuff"})


def _alternation(words: Iterable[str]) -> re.Pattern:
    ordered = sorted(set(words), key=lambda w: (-len(w), w))
    return re.compile(r"\b(?:" + "|".join(re.escape(w) for w in ordered) + r")\b", re.I)


_ACTION_RE = _alternation(ACTION_VERBS)
_LOCATION_RE = _alternation(LOCATION_NOUNS + LOCATION_PREPOSITIONS)
_LEADING = tuple(sorted(set(ACTION_VERBS) | set(LOCATION_PREPOSITIONS), key=len, reverse=True))


def has_action(step: str) -> bool:
    return bool(_ACTION_RE.search(step))


def has_location(step: str) -> bool:
    return bool(_LOCATION_RE.search(step))


def has_object(step: str) -> bool:
    for piece in re.findall(r"\b\w+(?:\s+\w+)?\b", step.lower()):
        if piece in _OBJECT_STOPWORDS or any(piece == w or piece.startswith(w + " ") for w in _LEADING):
            continue
        if len(piece) > 1 and piece not in _PRONOUN_ONLY:
            return True
    return False


def step_is_executable(step: str) -> bool:
    return has_action(step) and has_object(step) and has_location(step)


def exec_score(plan: list[str]) -> float | None:
    """Exec: share of steps with an action, an object and a location; None for an empty plan."""
    if not plan:
        return None
    return round(sum(step_is_executable(s) for s in plan) / len(plan), 4)


# =============================================================================================
# Planning: verb normalization, tokens (METHOD_NOTES 1.3-1.4)
# =============================================================================================

FILLER = "_filler_"
_BASE_SYNONYMS = {
    "grab": "grasp", "hold": "grasp", "grip": "grasp", "pick up": "grasp", "take": "grasp", "get": "grasp",
    "put": "place", "set": "place", "lay": "place", "rest": "place", "drop": "place", "position": "place",
    "carry": "move", "bring": "move", "transfer": "move", "transport": "move",
    "twist": "turn", "rotate": "turn", "switch": "turn", "turn on": "turn", "turn off": "turn",
    "wash": "wash", "clean": "wash", "scrub": "wash", "rinse": "rinse",
    "cut": "cut", "slice": "cut", "chop": "cut", "dice": "cut",
    "pour": "pour", "drizzle": "pour", "add": "pour", "open": "open", "close": "close", "shut": "close",
    "stir": "stir", "mix": "stir", "whisk": "stir", "peel": "peel", "reach": "reach", "extend": "reach",
    "wipe": "wipe", "fill": "fill", "refill": "fill", "the person is": "",
}
_INFLECTIONS = {
    "grasp": "grasping grasps grasped picking picks picked grabbing grabs grabbed taking takes took taken "
             "holding holds held getting gets got",
    "place": "placing places placed putting puts setting sets laying lays laid dropping drops dropped "
             "positioning positions positioned",
    "move": "moving moves moved carrying carries carried bringing brings brought transferring transfers transferred",
    "turn": "turning turns turned twisting twists twisted rotating rotates rotated switching switches switched",
    "wash": "washing washes washed cleaning cleans cleaned scrubbing scrubs scrubbed",
    # unlike the reference implementation, every rinse form stays "rinse" ("rinses X" is not "wash")
    "rinse": "rinsing rinses rinsed",
    "cut": "cutting cuts slicing slices sliced chopping chops chopped dicing dices diced",
    "pour": "pouring pours poured drizzling drizzles drizzled adding adds added",
    "open": "opening opens opened", "close": "closing closes closed shutting shuts",
    "stir": "stirring stirs stirred mixing mixes mixed whisking whisks whisked",
    "peel": "peeling peels peeled", "reach": "reaching reaches reached extending extends extended",
    "wipe": "wiping wipes wiped", "fill": "filling fills filled refilling refills refilled",
    "prepare": "preparing prepares prepared", "cook": "cooking cooks cooked", "use": "using uses used",
    "begin": "beginning begins began starting starts started", "continue": "continuing continues continued",
    "knead": "kneading kneads kneaded", "fold": "folding folds folded", "press": "pressing presses pressed",
    "shake": "shaking shakes shook shaken", "squeeze": "squeezing squeezes squeezed",
    "drain": "draining drains drained", "boil": "boiling boils boiled", "fry": "frying fries fried",
}
VERB_SYNONYMS: dict[str, str] = dict(_BASE_SYNONYMS)
for _canon, _forms in _INFLECTIONS.items():
    VERB_SYNONYMS.setdefault(_canon, _canon)
    for _form in _forms.split():
        VERB_SYNONYMS.setdefault(_form, _canon)
for _canon in set(v for v in _BASE_SYNONYMS.values() if v):
    VERB_SYNONYMS.setdefault(_canon, _canon)
_SYNONYM_KEYS = sorted(VERB_SYNONYMS, key=lambda k: (-len(k), k))
_SUBJECT_WORDS = frozenset({"person", "a", "the", "he", "she", "they", "it", "user", "participant", "subject"})
_PERSON_PREFIX = re.compile(r"^(?:(?:the|a)\s+)?person(?:\s+|$)(?:(?:is|are|was|were|will|begins?(?:\s+to)?|continues?(?:\s+to)?)(?:\s+|$))?")
_PRONOUN_PREFIX = re.compile(r"^(?:he|she|they|it)(?:\s+|$)(?:(?:is|are|was|were|will|then)(?:\s+|$))?")


def stem(word: str) -> str:
    """Strip the first fitting suffix of ing/ied/ies/ed/es/s, then one letter of a final double."""
    for suffix in ("ing", "ied", "ies", "ed", "es", "s"):
        if word.endswith(suffix) and len(word) > len(suffix) + 2:
            word = word[: -len(suffix)]
            break
    if len(word) >= 3 and word[-1] == word[-2]:
        word = word[:-1]
    return word


def extract_action_verb(text: str) -> str:
    """The normalized action verb of a step ("_filler_" when it has none)."""
    t = text.lower().strip()
    t = re.sub(r"^\s*\d+\s*[.)]\s*", "", t)
    t = _PERSON_PREFIX.sub("", t)
    t = _PRONOUN_PREFIX.sub("", t).strip()
    for key in _SYNONYM_KEYS:
        if t == key or t.startswith(key + " ") or (
            key.endswith(("s", "h", "x")) and (t.startswith(key + "es ") or t.startswith(key + "s "))
        ):
            return VERB_SYNONYMS[key] or FILLER
    words = re.findall(r"[a-z_]+", t)
    if not words:
        return FILLER
    head = words[0]
    if head in _SUBJECT_WORDS:
        if len(words) < 2 or words[1] in _SUBJECT_WORDS:
            return FILLER
        head = words[1]
    stemmed = stem(head)
    return VERB_SYNONYMS.get(head) or VERB_SYNONYMS.get(stemmed) or stemmed


STOPWORDS = frozenset(
    "the a an is are was were be to of in on at and or for with by from this that it its person participant "
    "tends typically usually while after before when their they user help".split()
    + [f"p{i:02d}" for i in range(1, 10)]
)
_TOKEN = re.compile(r"\b[a-z][a-z\-]{2,}\b")


def tokenize(text: str) -> set[str]:
    return {stem(w) for w in _TOKEN.findall(text.lower()) if w not in STOPWORDS}


def jaccard(a: set[str], b: set[str]) -> float:
    return len(a & b) / len(a | b) if a and b else 0.0


def _reference_text(step: Any) -> str:
    if isinstance(step, dict):
        return str(step.get("narration") or step.get("action") or "")
    return str(step)


# =============================================================================================
# Planning: OrderExec
# =============================================================================================

_lcs = lcs_length


def order_exec(plan: list[str], reference: list[Any], mode: Literal["lcs", "prefix"] = "lcs",
               require_executable: bool = True) -> float | None:
    """OrderExec = LCS(v(plan), v(reference)) / |v(reference)| (paper), or with mode="prefix" the
    reference implementation's greedy in-order match that stops at the first reference verb it
    cannot find. Plan steps count only when executable (action, object and location).
    None when the reference has no verbs."""
    ref = [v for v in (extract_action_verb(_reference_text(s)) for s in reference) if v not in ("", FILLER)]
    if not ref:
        return None
    steps = [s for s in plan if step_is_executable(s)] if require_executable else list(plan)
    verbs = [extract_action_verb(s) for s in steps]
    verbs = ["" if v == FILLER else v for v in verbs]
    if mode == "lcs":
        matched = _lcs([v for v in verbs if v], ref)
    elif mode == "prefix":
        matched, pointer = 0, 0
        for verb in ref:
            while pointer < len(verbs) and verbs[pointer] != verb:
                pointer += 1
            if pointer == len(verbs):
                break
            matched += 1
            pointer += 1
    else:
        raise ValueError(f"order_exec mode must be 'lcs' or 'prefix', got {mode!r}")
    return round(matched / len(ref), 4)


# =============================================================================================
# Planning: routine matching, KeyObj, PrefAdh
# =============================================================================================

ROUTINE_MATCH_THRESHOLD = 0.10
PREFERENCE_RELEVANCE = 0.05
COLOR_WORDS = frozenset(
    "black white red green blue yellow silver grey gray brown pink orange purple gold transparent clear metal metallic".split()
)
KITCHEN_NOUNS = tuple(
    "pot pan wok saucepan kettle bowl plate dish cup mug glass bottle jar can tin container tray board tupperware "
    "box bag basket carton knife spoon fork spatula peeler grater tongs whisk ladle strainer colander opener scoop "
    "microwave toaster blender stove oven hob fridge refrigerator dishwasher sink freezer cooker counter countertop "
    "drawer cabinet cupboard shelf rack table tap faucet burner grill worktop bread toast potato onion garlic carrot "
    "tomato pepper vegetable veg meat chicken rice pasta egg milk cheese butter oil salt sugar flour sauce spice "
    "cereal fruit apple banana lemon herb seasoning bok choy noodle broth cloth sponge towel soap detergent spray "
    "bin trash rubbish tissue paper wipe lid cap handle skin core wrapper peel rind".split()
)
KITCHEN_NOUN_STEMS = frozenset(stem(n) for n in KITCHEN_NOUNS)


def _items(values: Any, key: str) -> list[str]:
    out = []
    for v in values or []:
        out.append(str(v.get(key, "")) if isinstance(v, dict) else str(v))
    return [s for s in out if s]


def routine_parts(routine: dict) -> tuple[str, list[str], list[str]]:
    """(goal, canonical step actions, key objects) of a routine / procedure template."""
    return (str(routine.get("goal", "")), _items(routine.get("canonical_steps"), "action"),
            _items(routine.get("key_objects"), "object"))


def match_routine(task_query: str, routines: list[dict]) -> tuple[dict | None, float]:
    """The routine with the strictly highest Jaccard between the query tokens and its goal, key
    objects and step actions; (None, best) when best < 0.10."""
    q = tokenize(task_query)
    best, best_score = None, 0.0
    for r in routines or []:
        goal, steps, objects = routine_parts(r)
        score = jaccard(q, tokenize(" ".join([goal, *objects, *steps])))
        if score > best_score:
            best, best_score = r, score
    return (best, best_score) if best_score >= ROUTINE_MATCH_THRESHOLD else (None, best_score)


def memory_nouns(object_names: Iterable[str], key_objects: Iterable[str] = ()) -> set[str]:
    """KB noun vocabulary: for each name, the stem of its last word plus the stems of its words of
    4+ letters that are not colours."""
    out = set()
    for name in [*object_names, *key_objects]:
        words = re.findall(r"[a-z]+", str(name).lower().replace("_", " "))
        if not words:
            continue
        out.add(stem(words[-1]))
        out.update(stem(w) for w in words if len(w) >= 4 and w not in COLOR_WORDS)
    return out


def key_obj(plan: list[str], task: dict, routines: list[dict] | None = None,
            object_names: Iterable[str] = ()) -> float | None:
    """KeyObj. Generalize: share of the reference steps' KB nouns (stemmed; the kitchen-noun list
    when the KB has none) that the plan mentions. Replay: share of the matched routine's key
    objects (duplicates kept) that the plan mentions (whole string or any word > 2 letters as a
    substring). None without references."""
    if not plan:
        return None
    text = " ".join(plan).lower()
    if str(task.get("task_id", "")).startswith("generalize_"):
        key_objs = [o for r in routines or [] for o in routine_parts(r)[2]]
        vocab = memory_nouns(object_names, key_objs) or set(KITCHEN_NOUN_STEMS)
        refs = set().union(*(tokenize(_reference_text(s)) for s in task.get("ground_truth_steps", []))) & vocab
        if not refs:
            return None
        return round(len(refs & tokenize(text)) / len(refs), 4)
    routine, _ = match_routine(str(task.get("task_query", "")), routines or [])
    if routine is None:
        return None
    refs = [o.lower().replace("_", " ") for o in routine_parts(routine)[2]]
    if not refs:
        return None
    hits = sum(1 for r in refs if r in text or any(len(w) > 2 and w in text for w in r.split()))
    return round(hits / len(refs), 4)


def pref_adh(plan: list[str], task_query: str, preferences: list[dict] | None) -> float | None:
    """PrefAdh: mean, over preferences relevant to the query (Jaccard >= 0.05 with their keywords,
    else their text), of the share of their tokens the plan contains. None if none are relevant."""
    if not plan or not preferences:
        return None
    text = " ".join(plan).lower()
    plan_tokens = tokenize(text)
    query = tokenize(task_query)
    drop = {"used", "typically", "use", "user"} | {stem(w) for w in ("used", "typically", "use", "user")}
    scores = []
    for p in preferences:
        keywords = p.get("keywords") if isinstance(p, dict) else None
        if keywords:
            content = set().union(*(tokenize(str(k)) for k in keywords))
        else:
            body = str(p.get("preference") or p.get("text") or "") if isinstance(p, dict) else str(p)
            content = tokenize(body) - drop
        if not content or jaccard(query, content) < PREFERENCE_RELEVANCE:
            continue
        scores.append(sum(1 for t in content if t in plan_tokens or t in text) / len(content))
    return round(mean(scores), 4) if scores else None


# =============================================================================================
# Planning: object grounding diagnostic
# =============================================================================================

def plan_nouns(steps: Iterable[Any], vocabulary: set[str]) -> set[str]:
    """Distinct kitchen-noun stems mentioned in the steps."""
    return set().union(set(), *(tokenize(_reference_text(s)) for s in steps)) & vocabulary


def _f1(p: float | None, r: float | None) -> float | None:
    if p is None or r is None:
        return None
    return 0.0 if p + r == 0 else round(2 * p * r / (p + r), 4)


def object_grounding(plan: list[str], reference: list[Any], kb_nouns: set[str]) -> dict[str, float | None]:
    """KBGround = |P∩K|/|P|; ObjGT-R = |P∩G|/|G|, -P = |P∩G|/|P|, -F1; GR = |P∩K∩G|/|K∩G|,
    GP = |P∩K∩G|/|P|, GF1. P, G: kitchen-noun stems (kitchen-noun list plus the KB's nouns) of
    the plan and of the reference steps; K: the KB's noun stems."""
    vocab = set(KITCHEN_NOUN_STEMS) | set(kb_nouns)
    P, G, K = plan_nouns(plan, vocab), plan_nouns(reference, vocab), set(kb_nouns)

    def ratio(a: set, b: set) -> float | None:
        return round(len(a) / len(b), 4) if b else None

    r, p = ratio(P & G, G), ratio(P & G, P)
    gr, gp = ratio(P & K & G, K & G), ratio(P & K & G, P)
    return {
        "kb_ground": ratio(P & K, P), "objgt_r": r, "objgt_p": p, "objgt_f1": _f1(p, r),
        "gr": gr, "gp": gp, "gf1": _f1(gp, gr),
    }


# =============================================================================================
# Planning: per task and per condition
# =============================================================================================

AXES = ("exec", "order_exec", "key_obj", "pref_adh", "kb_ground", "objgt_r", "objgt_p", "objgt_f1", "gr", "gp", "gf1")
RGP_AXES = ("order_exec", "key_obj", "pref_adh")


def order_reference(task: dict, routines: list[dict] | None,
                    replay_reference: Literal["routine", "ground_truth"] = "routine") -> tuple[list[Any], str]:
    """(reference steps, metric_source). Generalize: the task's ground_truth_steps. Replay: the
    matched routine's canonical steps (paper), or the task's ground truth (reference code)."""
    if str(task.get("task_id", "")).startswith("generalize_") or replay_reference == "ground_truth":
        return list(task.get("ground_truth_steps", [])), "ground_truth_steps"
    routine, _ = match_routine(str(task.get("task_query", "")), routines or [])
    if routine is None:
        return [], "no_matching_routine"
    return routine_parts(routine)[1], "routine_skill"


def score_plan(
    plan: list[str],
    task: dict,
    routines: list[dict] | None = None,
    preferences: list[dict] | None = None,
    object_names: Iterable[str] = (),
    order_mode: Literal["lcs", "prefix"] = "lcs",
    replay_reference: Literal["routine", "ground_truth"] = "routine",
) -> dict[str, Any]:
    """Every planning metric for one task; None marks an undefined value (and `empty` an empty plan).

    `routines`/`preferences`/`object_names` are the participant's consolidated memory (the paper
    uses the MEMORA-full bank for every condition)."""
    object_names = list(object_names)
    reference, source = order_reference(task, routines, replay_reference)
    key_objs = [o for r in routines or [] for o in routine_parts(r)[2]]
    kb = memory_nouns(object_names, key_objs)
    out: dict[str, Any] = {"task_id": task.get("task_id"), "empty": not plan, "metric_source": source}
    if not plan:
        out.update({a: None for a in AXES})
        return out
    out["exec"] = exec_score(plan)
    out["order_exec"] = order_exec(plan, reference, order_mode) if reference else None
    out["key_obj"] = key_obj(plan, task, routines, object_names)
    out["pref_adh"] = pref_adh(plan, str(task.get("task_query", "")), preferences)
    out.update(object_grounding(plan, task.get("ground_truth_steps", []), kb))
    return out


def planning_panel(task_scores: list[dict]) -> dict[str, Any]:
    """Condition-level means of every axis over the tasks where it is defined (empty plans are
    excluded and counted), and RGP = mean of the defined OrderExec, KeyObj and PrefAdh means."""
    scored = [s for s in task_scores if not s.get("empty")]
    out: dict[str, Any] = {"n_plans_scored": len(scored), "n_empty_plans": len(task_scores) - len(scored)}
    for axis in AXES:
        values = [s[axis] for s in scored if s.get(axis) is not None]
        out[axis] = round(mean(values), 4) if values else None
        out[f"n_{axis}"] = len(values)
    defined = [out[a] for a in RGP_AXES if out[a] is not None]
    out["rgp"] = round(mean(defined), 4) if defined else None
    return out


def rgp(order_exec_mean: float | None, key_obj_mean: float | None, pref_adh_mean: float | None) -> float | None:
    """RGP from condition-level means; undefined components are skipped."""
    defined = [v for v in (order_exec_mean, key_obj_mean, pref_adh_mean) if v is not None]
    return round(mean(defined), 4) if defined else None
