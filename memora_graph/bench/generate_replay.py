"""Planning Replay generation: the paper's deterministic segmentation, typing and selection.

Per video: hard split on gaps > 30 s; soft split on gaps > 10 s where the verb category
changes between two non-general categories and the next action confirms the new one; short
segments merged forward, long ones cut into near-even chunks; 3-15 steps kept. Each segment is
typed from verb-category shares over non-filler verbs, given a templated "Help PXX ..." query,
scored, and up to 12 per participant are selected (at most 4 per type, then overflow fill).
Tasks whose narrations repeat too much (repeat rate > 0.70) move to an audit bucket. EPIC
nouns are matched against the bank's object registry (and nothing else from memory) to add
`enriched_narration` and `matched_object`; without a registry the steps stay un-enriched.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass, field

from memora_graph.bench.behaviour import Behaviour, ActionRow, clock, noun_text
from memora_graph.bench.tasks import MatchedObject, ReplayStep, ReplayTask

CLEANUP = frozenset({"wash", "rinse", "clean", "wipe", "dry", "sponge", "scrub", "squeeze"})
COOKING = frozenset({
    "fry", "boil", "cook", "bake", "roast", "simmer", "heat", "stir", "flip", "turn-over", "pour-into",
    "pour-from", "pour", "mix", "season", "add", "fold", "stretch", "roll", "roll-out", "shape", "knead",
    "spread",
})
PREP = frozenset({"cut", "chop", "peel", "slice", "grate", "crush", "mash", "break"})
SETUP = frozenset({
    "turn-on", "turn-off", "switch-on", "switch-off", "adjust", "check", "shake", "scoop", "sprinkle",
    "fill-with", "empty",
})
FILLER = frozenset({
    "pick-up", "put-down", "open", "close", "take", "put", "get", "hold", "put-in", "put-into", "put-on",
    "put-onto", "move", "move-into",
})
CATEGORIES = {"cleanup": CLEANUP, "cooking": COOKING, "prep": PREP, "setup": SETUP}
# thresholds are tested in this order
_PRECEDENCE = ("cleanup", "cooking", "prep", "setup")
_TIE_ORDER = ("setup", "cleanup", "cooking", "prep")
_TYPE_OF = {
    "cleanup": "cleanup_organization", "cooking": "multi_step_cooking", "prep": "meal_preparation",
    "setup": "object_retrieval_setup",
}
_THRESHOLD = {"cleanup": 0.35, "cooking": 0.3, "prep": 0.3, "setup": 0.3}
STORAGE_NOUNS = frozenset({
    "fridge", "freezer", "cupboard", "drawer", "cabinet", "shelf", "pantry", "container", "jar", "box",
    "bag", "tupperware", "rack", "basket", "package", "packet", "tin", "can",
})
# Tools and fixtures are not what a request is about ("clean the sink", not "clean the cloth").
UTENSIL_NOUNS = frozenset({
    "tap", "hand", "knife", "spoon", "fork", "spatula", "board", "chopping board", "cutting board",
    "sponge", "cloth", "towel", "lid", "ladle", "peeler", "potato peeler", "grater", "whisk", "tongs",
    "scissors", "cutlery", "water", "glove", "gloves", "liquid", "washing liquid", "button", "knob",
})
DISH_NOUNS = frozenset({
    "plate", "bowl", "cup", "glass", "mug", "pan", "pot", "dish", "cutlery", "fork", "spoon", "knife",
    "lid", "tray", "jug", "saucepan", "wok", "colander",
})
DISH_WASHING = frozenset({"wash", "rinse", "scrub", "sponge", "clean"})

MAX_GAP_HARD = 30.0
MAX_GAP_SOFT = 10.0


@dataclass
class ReplayConfig:
    min_steps: int = 3
    max_steps: int = 15
    target_steps: int = 9
    per_participant: int = 12
    per_type: int = 4
    max_repeat_rate: float = 0.70
    accept_match_score: float = 4.0


def verb_category(verb: str) -> str:
    """cleanup / cooking / prep / setup / filler / other for an EPIC verb as annotated."""
    for name, verbs in CATEGORIES.items():
        if verb in verbs:
            return name
    return "filler" if verb in FILLER else "other"


def split_category(verb: str) -> str:
    """The coarser categories used for soft splits: cleanup, cooking, prep or general."""
    cat = verb_category(verb)
    return cat if cat in ("cleanup", "cooking", "prep") else "general"


def segment_video(steps: list[ActionRow], config: ReplayConfig | None = None) -> list[list[ActionRow]]:
    """Split one video's time-ordered steps into candidate segments of min..max steps."""
    config = config or ReplayConfig()
    if not steps:
        return []
    segments: list[list[ActionRow]] = [[steps[0]]]
    for i in range(1, len(steps)):
        gap = max(0.0, steps[i].start_s - steps[i - 1].stop_s)
        prev_cat, cat = split_category(steps[i - 1].verb), split_category(steps[i].verb)
        confirmed = i + 1 < len(steps) and split_category(steps[i + 1].verb) == cat
        soft = gap > MAX_GAP_SOFT and "general" not in (prev_cat, cat) and prev_cat != cat and confirmed
        if gap > MAX_GAP_HARD or soft:
            segments.append([steps[i]])
        else:
            segments[-1].append(steps[i])
    merged: list[list[ActionRow]] = []
    carry: list[ActionRow] = []
    for seg in segments:
        seg = carry + seg
        carry = []
        if len(seg) < config.min_steps:
            carry = seg  # merged forward into the next segment
        else:
            merged.append(seg)
    if carry:
        if merged:
            merged[-1] = merged[-1] + carry  # a short tail joins the previous segment
        else:
            merged.append(carry)
    out = []
    for seg in merged:
        n = len(seg)
        if n > config.max_steps:
            k = max(math.ceil(n / config.max_steps), min(n // 3, math.ceil(n / config.target_steps)))
            base, extra = divmod(n, k)  # near-even: the first `extra` chunks take one more step
            start = 0
            for j in range(k):
                size = base + (1 if j < extra else 0)
                out.append(seg[start:start + size])
                start += size
        else:
            out.append(seg)
    return [seg for seg in out if config.min_steps <= len(seg) <= config.max_steps]


def category_shares(verbs: list[str]) -> dict[str, float]:
    meaningful = [v for v in verbs if v not in FILLER]
    if not meaningful:
        return {}
    counts = Counter(verb_category(v) for v in meaningful)
    return {name: counts.get(name, 0) / len(meaningful) for name in _PRECEDENCE}


def classify_task(verbs: list[str], nouns: list[str]) -> str:
    """Task type from verb-category shares over non-filler verbs (paper Table 'taxonomy').

    Tie-break (the paper names tie-break rules without listing them): among the categories
    with the largest share, the first of setup, cleanup, cooking, prep. With this rule every
    task type of the calibration files is reproduced from its steps.
    """
    storage = any(n in STORAGE_NOUNS or n.split()[-1] in STORAGE_NOUNS for n in nouns)
    shares = category_shares(verbs)
    if not shares:
        return "object_retrieval_setup" if storage else "routine_reproduction"
    for name in _PRECEDENCE:
        if shares[name] > _THRESHOLD[name]:
            return _TYPE_OF[name]
    top = max(shares.values())
    if top < 0.15:
        return "routine_reproduction"
    tied = [name for name in _TIE_ORDER if shares[name] == top]
    return _TYPE_OF[tied[0]]


def _ranked(values: list[str]) -> list[str]:
    counts = Counter(values)
    first = {}
    for i, v in enumerate(values):
        first.setdefault(v, i)
    return sorted(counts, key=lambda v: (-counts[v], first[v]))


def main_noun(nouns: list[str]) -> str:
    """The most frequent non-utensil noun (ties: first seen)."""
    ranked = _ranked(nouns)
    for n in ranked:
        if n not in UTENSIL_NOUNS and n.split()[-1] not in UTENSIL_NOUNS:
            return n
    return ranked[0] if ranked else "items"


_CATEGORY_OF_TYPE = {v: k for k, v in _TYPE_OF.items()}


def task_query(pid: str, task_type: str, verbs: list[str], nouns: list[str]) -> str:
    """The templated request; {noun} is the most frequent non-utensil noun, looked for first
    among the steps whose verbs gave the task its type ("clean the sink", not "the tofu")."""
    category = _CATEGORY_OF_TYPE.get(task_type)
    typed = [n for v, n in zip(verbs, nouns) if category and verb_category(v) == category]
    typed = [n for n in typed if n not in UTENSIL_NOUNS and n.split()[-1] not in UTENSIL_NOUNS]
    noun = main_noun(typed) if typed else main_noun(nouns)
    vset = set(verbs)
    if task_type == "cleanup_organization":
        dishes = [n for n in nouns if n.split()[-1] in DISH_NOUNS]
        if vset & DISH_WASHING and "dry" in vset and len(dishes) * 2 >= len(nouns):
            return f"Help {pid} wash and dry the dishes."
        if vset & DISH_WASHING:
            return f"Help {pid} wash the {noun}."
        if "wipe" in vset:
            return f"Help {pid} wipe down the {noun}."
        return f"Help {pid} clean the {noun}."
    if task_type == "multi_step_cooking":
        if vset & {"stir", "fry", "flip", "turn-over"}:
            return f"Help {pid} stir-fry the {noun}."
        if vset & {"knead", "roll", "roll-out", "shape", "fold", "stretch"}:
            return f"Help {pid} shape the {noun}."
        if vset & {"pour", "pour-into", "pour-from", "mix"}:
            return f"Help {pid} mix and pour the {noun}."
        return f"Help {pid} cook the {noun}."
    if task_type == "meal_preparation":
        if "peel" in vset:
            return f"Help {pid} peel and prepare the {noun}."
        return f"Help {pid} cut and prepare the {noun}."
    if task_type == "object_retrieval_setup":
        if any(n in STORAGE_NOUNS or n.split()[-1] in STORAGE_NOUNS for n in nouns):
            return f"Help {pid} get items from storage and set up."
        return f"Help {pid} get the {noun} ready."
    return f"Help {pid} complete the kitchen routine."


def segment_score(verbs: list[str], config: ReplayConfig | None = None) -> float:
    """(1 - |n - 9| / 15) + verb diversity + non-filler share."""
    config = config or ReplayConfig()
    n = len(verbs)
    return (1 - abs(n - config.target_steps) / 15) + len(set(verbs)) / n + sum(v not in FILLER for v in verbs) / n


def repeat_rate(narrations: list[str]) -> float:
    """1 - unique / total narrations."""
    return 1 - len(set(narrations)) / len(narrations) if narrations else 0.0


# ---------------------------------------------------------------------------------------------
# Noun -> registry object matching (the bank's object registry, nothing else from memory)
# ---------------------------------------------------------------------------------------------

SYNONYMS = {
    "tap": ["faucet"], "faucet": ["tap"], "cloth": ["dishcloth", "rag", "towel"], "towel": ["cloth", "tea towel"],
    "bin": ["trash", "rubbish", "garbage", "trash can"], "rubbish": ["trash", "bin", "garbage"],
    "hob": ["stove", "cooktop", "burner"], "stove": ["hob", "cooktop"], "fridge": ["refrigerator"],
    "cupboard": ["cabinet"], "cabinet": ["cupboard"], "pan": ["frying pan", "skillet", "saucepan"],
    "pot": ["saucepan", "cooking pot"], "sponge": ["scrubber", "scourer"], "counter": ["countertop", "worktop"],
    "top": ["countertop", "counter", "worktop"], "worktop": ["countertop", "counter"], "plate": ["dish"],
    "glass": ["cup", "tumbler"], "cup": ["mug", "glass"], "mug": ["cup"], "container": ["tupperware", "box"],
    "liquid": ["soap", "detergent", "dish soap"], "washing liquid": ["dish soap", "detergent", "soap"],
    "board": ["cutting board", "chopping board"], "chopping board": ["cutting board"], "rack": ["drying rack", "dish rack"],
    "drying rack": ["dish rack", "rack"], "kettle": ["electric kettle"], "colander": ["strainer"],
}
_WORD = re.compile(r"[a-z]+")


def _words(text: str) -> list[str]:
    return _WORD.findall(text.lower().replace("_", " "))


def _contains(haystack: list[str], needle: list[str]) -> bool:
    n = len(needle)
    return n > 0 and any(haystack[i:i + n] == needle for i in range(len(haystack) - n + 1))


def match_score(noun: str, obj: MatchedObject) -> float:
    """Paper 6 scoring: exact 10, noun in id 8, noun in name 7, reverse containment 6,
    token overlap >= 50% -> 3 + overlap, synonym 6 (equal) / 4 (contained). Containment is
    by whole words, so 'hand' does not match 'handheld'."""
    nw, idw, namew = _words(noun), _words(obj.memory_id), _words(obj.memory_name)
    if not nw:
        return 0.0
    if nw == namew or nw == idw:
        return 10.0
    if _contains(idw, nw):
        return 8.0
    if _contains(namew, nw):
        return 7.0
    if (namew and _contains(nw, namew)) or (idw and _contains(nw, idw)):
        return 6.0
    best = 0.0
    overlap = len(set(nw) & (set(namew) | set(idw))) / len(set(nw))
    if overlap >= 0.5:
        best = 3.0 + overlap
    phrase = " ".join(nw)
    for syn in SYNONYMS.get(phrase, []) + SYNONYMS.get(nw[-1], []):
        sw = _words(syn)
        if sw == namew or sw == idw:
            best = max(best, 6.0)
        elif _contains(namew, sw) or _contains(idw, sw):
            best = max(best, 4.0)
    return best


def match_object(noun: str, registry: list[MatchedObject], accept: float = 4.0) -> MatchedObject | None:
    best, best_score = None, 0.0
    for obj in registry:  # registry is sorted by memory_id, so ties go to the first id
        score = match_score(noun, obj)
        if score > best_score:
            best, best_score = obj, score
    return best if best_score >= accept else None


def enrich_narration(narration: str, noun: str, obj: MatchedObject) -> str:
    """'wash sink' + {silver, stainless steel, on counter} -> 'wash silver stainless steel sink on counter'."""
    attrs = " ".join(a for a in (obj.color.strip(), obj.material.strip()) if a)
    words = narration.split()
    low = [w.lower() for w in words]
    target = _words(noun)
    at = None
    for i in range(len(low)):
        if target and [w.strip(",.") for w in low[i:i + len(target)]] == target:
            at = i
            break
    if at is None and target:
        head = target[-1]
        at = next((i for i, w in enumerate(low) if w.strip(",.").startswith(head)), None)
    text = narration
    if attrs:
        already = attrs.lower() in narration.lower()
        if not already:
            text = " ".join(words[:at] + [attrs] + words[at:]) if at is not None else f"{narration} ({attrs})"
    loc = obj.location.strip()
    if loc and loc.lower() not in text.lower():
        first = loc.split()[0].lower()
        text += f" {loc}" if first in {"on", "in", "at", "inside", "under", "near", "beside", "by", "above", "next"} else f" at {loc}"
    return text


# ---------------------------------------------------------------------------------------------
# Suite construction
# ---------------------------------------------------------------------------------------------

@dataclass
class ReplayResult:
    tasks: list[ReplayTask] = field(default_factory=list)
    filtered: list[ReplayTask] = field(default_factory=list)  # repeat rate above the limit
    n_candidates: int = 0


def _step_record(step: ActionRow, registry: list[MatchedObject] | None, accept: float) -> ReplayStep:
    record = ReplayStep(
        narration_id=step.narration_id, narration=step.narration, verb=step.verb, noun=step.noun,
        start_time=clock(step.start_s), end_time=clock(step.stop_s),
    )
    if registry:
        obj = match_object(noun_text(step.noun), registry, accept)
        if obj is not None:
            record.enriched_narration = enrich_narration(step.narration, noun_text(step.noun), obj)
            record.matched_object = obj.model_copy()
    return record


def registry_objects(registry: list[dict], where: str = "registry") -> list[tuple[str | None, MatchedObject]]:
    """Validate registry entries {memory_id, memory_name, color, material, location[, video_id]}."""
    from pydantic import ValidationError

    from memora_graph.errors import DataError

    out = []
    for i, entry in enumerate(registry):
        if not isinstance(entry, dict):
            raise DataError(f"{where}[{i}]: expected an object with memory_id, memory_name, color, material, location")
        fields = {k: entry.get(k, "") for k in ("memory_id", "memory_name", "color", "material", "location")}
        try:
            obj = MatchedObject.model_validate({k: ("" if v is None else v) for k, v in fields.items()})
        except ValidationError as exc:
            raise DataError(f"{where}[{i}] (memory_id {entry.get('memory_id')!r}): {exc.errors()[0]['msg']}") from None
        if not obj.memory_id or not obj.memory_name:
            raise DataError(f"{where}[{i}]: memory_id and memory_name must not be empty")
        out.append((entry.get("video_id"), obj))
    return out


def registry_for_video(registry: list[dict], video_id: str) -> list[MatchedObject]:
    """Entries of that video (the paper matches within the video's registry) plus entries without a video."""
    objects = [obj for vid, obj in registry_objects(registry) if vid in (None, "", video_id)]
    return sorted(objects, key=lambda o: o.memory_id)


def candidate_tasks(behaviour: Behaviour, config: ReplayConfig | None = None,
                    videos: list[str] | None = None) -> list[dict]:
    config = config or ReplayConfig()
    pid = behaviour.participant_id
    out = []
    for video in behaviour.videos:
        if videos is not None and video not in videos:
            continue
        for index, seg in enumerate(segment_video(behaviour.steps_by_video[video], config)):
            verbs = [s.verb for s in seg]
            nouns = [noun_text(s.noun) for s in seg]
            task_type = classify_task(verbs, nouns)
            out.append({
                "task_id": f"plan_{video}_{index:03d}", "video_id": video, "steps": seg, "verbs": verbs,
                "nouns": nouns, "task_type": task_type, "query": task_query(pid, task_type, verbs, nouns),
                "score": segment_score(verbs, config), "shares": category_shares(verbs),
            })
    return out


def select_tasks(cands: list[dict], config: ReplayConfig | None = None) -> list[dict]:
    """Greedy by score with at most per_type per type, then overflow fill up to per_participant."""
    config = config or ReplayConfig()
    ranked = sorted(cands, key=lambda c: (-c["score"], c["task_id"]))
    chosen, per_type = [], Counter()
    for c in ranked:
        if len(chosen) >= config.per_participant:
            break
        if per_type[c["task_type"]] < config.per_type:
            chosen.append(c)
            per_type[c["task_type"]] += 1
    for c in ranked:
        if len(chosen) >= config.per_participant:
            break
        if c not in chosen:
            chosen.append(c)
    seen: Counter = Counter()
    for c in chosen:  # duplicate queries get the segment's second object, else its video
        seen[c["query"]] += 1
    used = set()
    for c in chosen:
        q = c["query"]
        if seen[q] > 1:
            noun = main_noun(c["nouns"])
            others = [n for n in _ranked(c["nouns"]) if n != noun]
            alt = f"{q[:-1]} ({others[0]})." if others else None
            q = alt if alt and alt not in used else f"{q[:-1]} [{c['video_id']}]."
        used.add(q)
        c["query"] = q
    return chosen


def generate_replay(behaviour: Behaviour, registry: list[dict] | None = None,
                    config: ReplayConfig | None = None, videos: list[str] | None = None) -> ReplayResult:
    """Replay tasks for one participant; `registry` is the bank's object registry (optional)."""
    config = config or ReplayConfig()
    pid = behaviour.participant_id
    cands = candidate_tasks(behaviour, config, videos)
    result = ReplayResult(n_candidates=len(cands))
    for c in select_tasks(cands, config):
        objects = registry_for_video(registry, c["video_id"]) if registry else None
        steps: list[ActionRow] = c["steps"]
        narrations = [s.narration for s in steps]
        rate = round(repeat_rate(narrations), 4)
        task = ReplayTask(
            task_id=c["task_id"], participant_id=pid, video_id=c["video_id"], task_type=c["task_type"],
            task_query=c["query"],
            ground_truth_steps=[_step_record(s, objects, config.accept_match_score) for s in steps],
            num_steps=len(steps), time_span_seconds=round(steps[-1].stop_s - steps[0].start_s, 1),
            primary_objects=_ranked(c["nouns"])[:5], primary_verbs=_ranked(c["verbs"])[:5],
            repeat_rate=rate,
            audit={"score": round(c["score"], 4), "category_shares": {k: round(v, 4) for k, v in c["shares"].items()},
                   "narration_ids": [s.narration_id for s in steps], "enriched": bool(objects),
                   # rows of the bundled subset without narration text read "verb noun" from the class keys
                   "class_key_steps": sum(s.text_source == "class_keys" for s in steps)},
        )
        (result.filtered if rate > config.max_repeat_rate else result.tasks).append(task)
    return result
