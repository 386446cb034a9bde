"""A validated consolidation reply -> the records of the bank: statements, contexts and activity
types normalised, and each item's support (episodes, segments, entities, videos) resolved by the
caller's `support`."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from memora_graph.consolidate import vocab
from memora_graph.consolidate.llm.handles import EntityNames
from memora_graph.consolidate.llm.prompts import ACTIVITY_TYPES, CONTEXTS, PromptLimits, clip_text
from memora_graph.consolidate.llm.replies import ConsolidationReply
from memora_graph.consolidate.records import (
    ActionSequence, OrganizationalHabit, StoragePreference, WorkflowPattern,
)
from memora_graph.text import uniq


def _context(value: str) -> str:
    v = value.strip().lower().replace("-", "_").replace(" ", "_")
    return v if v in CONTEXTS else "default"


def normalized_activity(value: str, steps: Iterable[str] = ()) -> str:
    v = value.strip().lower().replace("-", "_").replace(" ", "_")
    if v in ACTIVITY_TYPES:
        return v
    words = " ".join([v, *steps]).lower()
    for key, kind in (("clean", "cleanup_organization"), ("wash", "cleanup_organization"),
                      ("cook", "multi_step_cooking"), ("fry", "multi_step_cooking"), ("boil", "multi_step_cooking"),
                      ("prep", "meal_preparation"), ("cut", "meal_preparation"), ("chop", "meal_preparation"),
                      ("setup", "object_retrieval_setup"), ("retriev", "object_retrieval_setup")):
        if key in words:
            return kind
    return vocab.ACTIVITY_TYPE[None]


def preposition_for(where: str) -> str:
    return "on" if {"rack", "counter", "board", "hob", "tray", "table", "worktop", "shelf", "stove", "top"} & set(
        where.lower().split()) else "in"


def _storage_statement(obj: str, where: str, context: str) -> str:
    return {
        "storage": f"Typically stores the {obj} {preposition_for(where)} the {where}",
        "after_use": f"After using the {obj}, usually puts it {preposition_for(where)} the {where}",
        "during_use": f"Usually uses the {obj} at the {where}",
        "default": f"Usually puts the {obj} {preposition_for(where)} the {where}",
    }[context]


def _slug(text: str) -> str:
    return "_".join(text.lower().split()) or "object"


def merge_videos(parts: Iterable[dict[str, int]]) -> dict[str, int]:
    out: Counter[str] = Counter()
    for p in parts:
        out.update(p)
    return dict(sorted(out.items()))


@dataclass
class Support:
    """What one consolidation item rests on, once its references are resolved."""

    episodes: list[str]
    segments: list[str]
    entities: list[str]
    videos: dict[str, int]
    count: int


def reply_records(reply: ConsolidationReply, support: Callable[[list[str]], Support], names: EntityNames,
             lim: PromptLimits) -> dict[str, list]:
    """A consolidation reply -> the record lists of VideoConsolidation / Consolidation."""
    cap = lim.items_per_list
    out: dict[str, list] = {"storage_preferences": [], "organizational_habits": [], "workflow_patterns": [],
                            "action_sequences": []}
    for it in reply.storage_preferences[:cap]:
        sp = support(it.supporting_episodes)
        obj, ctx, where = it.object.lower(), _context(it.context), it.preferred_location.lower()
        out["storage_preferences"].append(StoragePreference(
            object=_slug(obj), object_name=obj, statement=_storage_statement(obj, where, ctx), preferred_location=where,
            context=ctx, count=sp.count, total=sp.count, confidence=it.confidence, supporting_episodes=sp.episodes,
            entities=uniq(sp.entities + names.entities([it.object])), videos=sp.videos))
    for it in reply.organizational_habits[:cap]:
        sp = support(it.supporting_episodes)
        out["organizational_habits"].append(OrganizationalHabit(
            trigger=it.trigger or it.habit, next_action=it.next_action, habit=it.habit, count=sp.count,
            trigger_count=sp.count, objects_involved=it.objects_involved, confidence=it.confidence,
            supporting_episodes=sp.episodes, entities=uniq(sp.entities + names.entities(it.objects_involved)),
            videos=sp.videos))
    for it in reply.workflow_patterns[:cap]:
        sp = support(it.supporting_episodes)
        out["workflow_patterns"].append(WorkflowPattern(
            pattern=it.pattern, category=it.category or "objects", use=it.use, then=it.then, objects=it.objects,
            count=sp.count, confidence=it.confidence, supporting_episodes=sp.episodes,
            entities=uniq(sp.entities + names.entities(it.objects)), videos=sp.videos))
    for it in reply.action_sequences[:cap]:
        sp = support(it.supporting_episodes)
        steps = [clip_text(x, 80) for x in it.key_steps][: lim.steps_per_skill]
        out["action_sequences"].append(ActionSequence(
            title=it.goal or it.pattern_name or " -> ".join(steps[:4]), steps=steps,
            activity_type=normalized_activity(it.activity_type, steps), key_objects=it.key_objects, count=sp.count,
            confidence=it.confidence, supporting_episodes=sp.episodes, segments=sp.segments,
            entities=uniq(sp.entities + names.entities(it.key_objects)), videos=sp.videos))
    return out
