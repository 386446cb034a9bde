"""Offline consolidation and inferred-knowledge enrichment (the paper's InfMem).

    from memora_graph.consolidate import finish_participant, consolidate_participant
    finish_participant(bank, "P03", embedder)            # after a build; --episodic skips it
    knowledge = consolidate_participant(store, "P03", embedder)   # on an open read-write store

Processors are looked up by name (`get_processors("deterministic")`); an LLM processor
registers with `register_processor` and returns the same records.
"""

from memora_graph.consolidate.memory import ParticipantMemory, load_memory
from memora_graph.consolidate.processors import (
    ConsolidationProcessor, EnrichmentProcessor, Processors, get_processors, processor_names, register_processor,
)
from memora_graph.consolidate.run import (
    InferredKnowledge, clear_inferred, consolidate_participant, finish_participant, infer, write_inferred,
)

__all__ = [
    "ConsolidationProcessor", "EnrichmentProcessor", "InferredKnowledge", "ParticipantMemory", "Processors",
    "clear_inferred", "consolidate_participant", "finish_participant", "get_processors", "infer", "load_memory",
    "processor_names", "register_processor", "write_inferred",
]
