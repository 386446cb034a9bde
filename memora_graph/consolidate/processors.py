"""The two offline processors behind one interface each, and the registry that picks them.

`ConsolidationProcessor` runs per completed video and then once per participant;
`EnrichmentProcessor` turns the participant slice plus its consolidation into routine skills and
generated preferences. The deterministic policies are the default (CPU, no model). An LLM
processor (roles "consolidation" and "enrichment" of `memora_graph.llm`) registers under its own
name with `register_processor` and returns the same records; evidence checking and storage do
not change.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from memora_graph.consolidate.memory import ParticipantMemory
from memora_graph.consolidate.records import Consolidation, Enrichment, VideoConsolidation
from memora_graph.errors import MemoraError


class ConsolidationProcessor(Protocol):
    name: str

    def consolidate_video(self, memory: ParticipantMemory, video: str) -> VideoConsolidation:
        """What one completed video shows: storage, habits, workflows, action sequences."""

    def consolidate_participant(self, memory: ParticipantMemory, per_video: list[VideoConsolidation]) -> Consolidation:
        """What repeats across the completed videos."""


class EnrichmentProcessor(Protocol):
    name: str

    def enrich(self, memory: ParticipantMemory, consolidation: Consolidation) -> Enrichment:
        """Routine skills and generated preferences, citing segment ids of `memory` only."""


@dataclass(frozen=True)
class Processors:
    name: str
    consolidation: ConsolidationProcessor
    enrichment: EnrichmentProcessor


_REGISTRY: dict[str, Callable[[], Processors]] = {}


def register_processor(name: str, factory: Callable[[], Processors]) -> None:
    if name in _REGISTRY:
        raise MemoraError(f"consolidation processor {name!r} is already registered")
    _REGISTRY[name] = factory


def get_processors(name: str = "deterministic") -> Processors:
    if name not in _REGISTRY:
        raise MemoraError(f"no consolidation processor {name!r}; registered: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]()


def processor_names() -> list[str]:
    return sorted(_REGISTRY)


def _deterministic() -> Processors:
    from memora_graph.consolidate.rules import RuleConsolidator, RuleEnricher

    return Processors("deterministic", RuleConsolidator(), RuleEnricher())


register_processor("deterministic", _deterministic)
