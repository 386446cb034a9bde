"""Model-backed offline consolidation and InfMem enrichment (roles "consolidation", "enrichment").

Four kinds of model step, each one call (plus the backend's one repair turn) answered as JSON
and validated with pydantic:

  consolidation, per completed video  the video's objects and its activity log, one line per
                                      10 s segment under a short handle (S1, S2, ...) ->
                                      storage preferences, organizational habits, workflow
                                      patterns and action sequences citing segment handles
  consolidation, across videos        the per-video findings under handles (F1, F2, ...) ->
                                      what holds for the participant, citing findings
  enrichment, routine skills          evidence items (E001, ...: the rule episodes of every
                                      video, then the consolidated patterns) -> routine skills
  enrichment, generated preferences   the same evidence items -> preferences with subtype,
                                      keywords and supporting_evidence_ids (the paper's pass)

Handles are mapped back to segment ids (`handles`). A handle or id the model invented is passed on
unchanged, so the collector in `run.py` drops it (and counts it) like any other id that is not
in the bank, and a record left with no existing evidence is not written. Object names link
records to entities only when they name an object of the memory. Prompts are bounded by
`PromptLimits` (segments, objects, findings and evidence items per prompt; characters per line).

A reply that stays invalid after the repair turn fails that step only: the failed call is in
the call log, the step is reported (`StepReport`) and logged as a warning, and the step adds no
records. A model server that cannot be reached raises.

The package, one module per idea: `replies` (the reply contract), `prompts` (versions, limits,
system prompts, line helpers), `handles` (prompt handles and object names -> ids),
`reply_records` (a consolidation reply -> records), `model_step` (the one-call step both
processors share), `consolidator`, `enricher`, and `factory` (make_llm_processors,
check_servers). The names below are the package's interface.
"""

from __future__ import annotations

from memora_graph.consolidate.llm.consolidator import LLMConsolidator
from memora_graph.consolidate.llm.enricher import LLMEnricher
from memora_graph.consolidate.llm.factory import check_servers, make_llm_processors
from memora_graph.consolidate.llm.handles import Handles
from memora_graph.consolidate.llm.model_step import DEFAULT_MODEL, OFFLINE_MESSAGE
from memora_graph.consolidate.llm.prompts import (
    ACTIVITY_TYPES, ALLOWED_SUBTYPES, CONSOLIDATION_SYSTEM, CONTEXTS, ENRICHMENT_SYSTEM, PROMPT_VERSIONS, PromptLimits,
)
from memora_graph.consolidate.llm.replies import (
    Confidence, ConsolidationReply, HabitItem, PreferenceItem, PreferencesReply, ProcedureItem, Refs, SkillItem,
    SkillsReply, StorageItem, Text, Texts, WorkflowItem,
)

__all__ = [
    "ACTIVITY_TYPES", "ALLOWED_SUBTYPES", "CONSOLIDATION_SYSTEM", "CONTEXTS", "DEFAULT_MODEL", "ENRICHMENT_SYSTEM",
    "OFFLINE_MESSAGE", "PROMPT_VERSIONS", "Confidence", "ConsolidationReply", "HabitItem", "Handles", "LLMConsolidator",
    "LLMEnricher", "PreferenceItem", "PreferencesReply", "ProcedureItem", "PromptLimits", "Refs", "SkillItem",
    "SkillsReply", "StorageItem", "Text", "Texts", "WorkflowItem", "check_servers", "make_llm_processors",
]
