"""The MEMORA-Bench metrics of one item, as pure functions (paper definitions; docs/evaluation.md).

Planning: Exec; OrderExec (LCS over normalized verbs by default, the reference implementation's
greedy prefix as an option); KeyObj; PrefAdh; KBGround; ObjGT-R/P/F1; GR/GP/GF1. Undefined values
are None and are skipped by the aggregates (`bench.aggregate`). Reading replies (answer letters,
plans) is `bench.answers`; the word lists and verb normalization are `bench.vocabulary`.
"""

from __future__ import annotations

import re
from statistics import mean
from typing import Any, Iterable, Literal

from memora_graph.bench.vocabulary import (
    ACTION_VERBS, FILLER, LOCATION_NOUNS, LOCATION_PREPOSITIONS, OBJECT_STOPWORDS, PRONOUN_ONLY, extract_action_verb,
)
from memora_graph.sequences import lcs_length
from memora_graph.text import COLOR_WORDS, KITCHEN_NOUN_STEMS, jaccard, stem, tokenize

# =============================================================================================
# Planning: Exec predicates
# =============================================================================================

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
        if piece in OBJECT_STOPWORDS or any(piece == w or piece.startswith(w + " ") for w in _LEADING):
            continue
        if len(piece) > 1 and piece not in PRONOUN_ONLY:
            return True
    return False


def step_is_executable(step: str) -> bool:
    return has_action(step) and has_object(step) and has_location(step)


def exec_score(plan: list[str]) -> float | None:
    """Exec: share of steps with an action, an object and a location; None for an empty plan."""
    if not plan:
        return None
    return round(sum(step_is_executable(s) for s in plan) / len(plan), 4)


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
