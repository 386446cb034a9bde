"""The two offline processors behind one interface each, and the registry that picks them.

`ConsolidationProcessor` runs per completed video and then once per participant;
`EnrichmentProcessor` turns the participant slice plus its consolidation into routine skills and
generated preferences. The deterministic policies are the default (CPU, no model). The LLM
processor (roles "consolidation" and "enrichment" of `memora_graph.llm`, in
`memora_graph.consolidate.llm`) is registered as "llm" and returns the same records; evidence
checking and storage do not change. This module is the interface and the registry; the built-in
processors are registered where they are run (run.py). A factory takes options, so one that needs a model server
is configured through the same lookup:

    get_processors("deterministic")
    get_processors("llm", options={"backend": "openai", "base_url": "http://127.0.0.1:8000/v1",
                                   "model": "Qwen/Qwen3.6-35B-A3B"})
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from memora_graph.consolidate.memory import ParticipantMemory
from memora_graph.consolidate.records import Consolidation, Enrichment, VideoConsolidation
from memora_graph.errors import MemoraError

if TYPE_CHECKING:
    from memora_graph.llm.backends import CallLog


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


@dataclass
class StepReport:
    """One model step of a processor (a video's consolidation, the participant pass, routine
    skills, preferences) and whether it produced records; a failed step contributes none."""

    participant: str
    step: str
    ok: bool
    error: str = ""


@dataclass(frozen=True)
class Processors:
    """The two processors of one run. Model-backed ones also bring the log their calls go to and
    the list they report their steps in; `infer` picks up what each participant added."""

    name: str
    consolidation: ConsolidationProcessor
    enrichment: EnrichmentProcessor
    call_log: CallLog | None = None
    reports: list[StepReport] | None = None
    concurrency: int = 1  # per-video consolidation calls in flight at once (model-backed processors)


_REGISTRY: dict[str, Callable[..., Processors]] = {}


def register_processor(name: str, factory: Callable[..., Processors]) -> None:
    """`factory(**options)` returns the processors; options are whatever `get_processors` is given."""
    if name in _REGISTRY:
        raise MemoraError(f"consolidation processor {name!r} is already registered")
    _REGISTRY[name] = factory


def get_processors(name: str = "deterministic", options: dict[str, Any] | None = None) -> Processors:
    """The processors registered as `name`, built with `options` (a factory's keyword arguments)."""
    if name not in _REGISTRY:
        raise MemoraError(f"no consolidation processor {name!r}; registered: {', '.join(sorted(_REGISTRY))}")
    factory = _REGISTRY[name]
    if not options:
        return factory()
    try:
        inspect.signature(factory).bind(**options)
    except TypeError as exc:
        raise MemoraError(f"consolidation processor {name!r} does not take these options ({exc})") from None
    return factory(**options)


def processor_names() -> list[str]:
    return sorted(_REGISTRY)
