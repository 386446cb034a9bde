"""The prompts: their versions and limits, the system prompts, and the helpers that write one line
of a prompt (clipped, evenly sampled, a narrated step as an action)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from memora_graph.consolidate import vocab
from memora_graph.consolidate.memory import MemoryStep, display

PROMPT_VERSIONS = {"video": "consolidate-video-v1", "participant": "consolidate-participant-v1",
                   "skills": "enrich-skills-v1", "preferences": "enrich-preferences-v1"}
CONTEXTS = ("storage", "during_use", "after_use", "default")
ACTIVITY_TYPES = tuple(sorted(set(vocab.ACTIVITY_TYPE.values())))
ALLOWED_SUBTYPES = ("tool", "storage", "habit", "workflow", "ingredient", "technique", "order", "other")
# Segment summaries that say nothing (the annotation path writes this for a turn without a narration).
EMPTY_SUMMARIES = frozenset({"", "no narrated action"})


@dataclass(frozen=True)
class PromptLimits:
    """What one prompt may hold; longer inputs are sampled evenly (in time order) or cut."""

    segments_per_video: int = 120
    objects_per_video: int = 40
    findings: int = 150  # per-video findings shown to the participant pass
    episodes: int = 80  # evidence items of the enrichment prompts (rule episodes) ...
    patterns: int = 30  # ... plus consolidated patterns
    steps_per_episode: int = 12
    line_chars: int = 220
    items_per_list: int = 12  # records asked for per list of a consolidation reply
    max_skills: int = 12
    max_preferences: int = 15
    steps_per_skill: int = 12


_CONSOLIDATION_FORMAT = """Answer with one JSON object and nothing else:
{"storage_preferences": [{"object": str, "preferred_location": str,
   "context": "storage" | "during_use" | "after_use" | "default", "confidence": 0-1, "evidence": str,
   "supporting_episodes": [handle, ...]}],
 "organizational_habits": [{"habit": str, "trigger": str, "next_action": str, "objects_involved": [str],
   "confidence": 0-1, "supporting_episodes": [handle, ...]}],
 "workflow_patterns": [{"pattern": str, "category": str, "use": str, "then": str, "objects": [str],
   "confidence": 0-1, "supporting_episodes": [handle, ...]}],
 "action_sequences": [{"pattern_name": str, "goal": str, "activity_type": str, "key_objects": [str],
   "key_steps": [str, ...], "confidence": 0-1, "supporting_episodes": [handle, ...]}]}
All four keys are required; a list may be empty. Every item cites at least one handle."""

CONSOLIDATION_SYSTEM = f"""You are the offline consolidation processor of a personal kitchen memory.
You read the completed memories of one person and infer only what they show: where the person keeps
and puts objects (storage preferences), what they habitually do next (organizational habits), how
kinds of objects flow from use to their place (workflow patterns), and recurring multi-step
procedures (action sequences). Do not add general cooking knowledge. Cite evidence only with the
handles given in the input; never make one up.
activity_type is one of: {", ".join(ACTIVITY_TYPES)}.
{_CONSOLIDATION_FORMAT}"""

ENRICHMENT_SYSTEM = """You are the InfMem enrichment processor of a personal kitchen memory. You convert
low-level evidence about one person into reusable participant-level memories for planning. Use only
the evidence ids supplied (E001, E002, ...), never others; prefer concrete object / action / context
statements over generic cooking knowledge. Answer with one JSON object and nothing else, in the
format the task asks for."""


def clip_text(text: Any, limit: int) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3].rstrip() + "..."


def short_number(x: float) -> str:
    return f"{round(float(x), 1):g}"


def evenly_sampled(items: Sequence, cap: int) -> list:
    """At most `cap` items, evenly spaced, in their order."""
    n = len(items)
    if n <= cap:
        return list(items)
    if cap <= 1:
        return list(items[:cap])
    return [items[round(i * (n - 1) / (cap - 1))] for i in range(cap)]


def action_text(s: MemoryStep) -> str:
    text = s.narration or s.text()
    if s.destination and s.destination != s.main.kind and display(s.destination) not in text:
        text += f" -> {display(s.destination)}"
    return text
