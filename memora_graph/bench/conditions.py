"""The seven memory conditions of the evaluation, in one registry.

A condition is a memory representation built from the same bank (the same layered perception
records), its read tools, and its prompt family:

    no_memory        Parametric          no memory, no tools
    flat_1d_raw      Flat-1D (raw)       chronological text records of the raw bank      search
    flat_1d_edited   Flat-1D (processed) the same, from the edited bank                   search
    graph_2d_raw     Graph-2D (raw)      networkx entity-relation graph of the raw bank  search, get_object_history, get_state_at_time
    graph_2d_edited  Graph-2D (processed) the same, from the edited bank
    memora_episodic  MEMORA-Episodic     typed stores, no consolidated knowledge          MEMORA episodic tools
    memora_full      MEMORA              typed stores + routines and preferences          + get_routine_skill, get_preferences

Names follow the reference implementation's result files; `label` is the paper's name. The
registry raises on a duplicate name or alias and lists the known names on an unknown lookup.
A condition's tools are the retrieval registry's specs of its tool family (`memory`: memora,
flat1d or graph2d); they are opened per (condition, participant): a tool set is bound to one
participant's memory and drops any argument its schema does not declare, so no call can reach
another participant.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from memora_graph.errors import MemoraError
from memora_graph.retrieve.registry import ToolSet, get_family, tool_set


class ConditionError(MemoraError):
    pass


@dataclass(frozen=True)
class Condition:
    name: str
    label: str
    prompt_family: str  # the prompt family (memora_graph.agent.prompts.FAMILIES); `memory` names the tool family
    bank: str  # which bank the representation is built from: none | raw | edited | episodic
    tools: tuple[str, ...]
    memory: str | None  # the tool family (memory representation) the tools read; None for Parametric
    aliases: tuple[str, ...] = ()
    description: str = ""

    def open_tools(self, banks: BankSet, participant: str) -> ToolSet | None:
        """This condition's tools bound to one participant's memory (None: no memory, no tools)."""
        if self.memory is None:
            return None
        family = get_family(self.memory)
        path = banks.path(self.bank)
        memory = banks.memory(f"{self.memory}:{self.bank}", participant, lambda: family.open(path, participant))
        return tool_set(self.memory, self.tools, participant, memory)


@dataclass
class BankSet:
    """The banks a run reads: the edited bank (MEMORA, processed baselines, metrics) and the raw
    bank (raw baselines). Memories are loaded on first use and kept for the run."""

    edited: Path
    raw: Path | None = None
    episodic: Path | None = None
    _memories: dict[tuple[str, str], Any] = field(default_factory=dict)

    def path(self, kind: str) -> Path:
        if kind == "episodic":
            if self.episodic is None:
                raise ConditionError("memora_episodic needs --episodic-bank DIR, a bank built with "
                                     "`memora build DIR --episodic` (no consolidated routines or preferences)")
            return Path(self.episodic)
        if kind == "raw":
            if self.raw is None:
                raise ConditionError("this condition needs a raw bank: pass --raw-bank DIR "
                                     "(built with `memora build DIR --mode raw`)")
            return Path(self.raw)
        return Path(self.edited)

    def memory(self, key: str, participant: str, loader: Callable[[], Any]) -> Any:
        k = (key, participant)
        if k not in self._memories:
            # Keep one participant's memories at a time: runs go participant by participant.
            for old in [o for o in self._memories if o[1] != participant]:
                closer = getattr(self._memories.pop(old), "close", None)
                if closer:
                    closer()
            self._memories[k] = loader()
        return self._memories[k]


MEMORA_EPISODIC_TOOLS = ("search", "search_objects", "get_object_history", "get_state_at_time", "search_activities",
                         "get_video_activities", "search_patterns")
MEMORA_FULL_TOOLS = MEMORA_EPISODIC_TOOLS + ("get_routine_skill", "get_preferences")
GRAPH_TOOLS = ("search", "get_object_history", "get_state_at_time")


# -- the registry ---------------------------------------------------------------------------------

_REGISTRY: dict[str, Condition] = {}
_ALIASES: dict[str, str] = {}
_FROZEN = False


def register(condition: Condition) -> Condition:
    if _FROZEN:
        raise ConditionError(f"the condition registry is frozen; cannot register {condition.name!r}")
    for key in (condition.name, *condition.aliases):
        if key in _REGISTRY or key in _ALIASES:
            raise ConditionError(f"a condition named {key!r} is already registered")
    _REGISTRY[condition.name] = condition
    for a in condition.aliases:
        _ALIASES[a] = condition.name
    return condition


def freeze() -> None:
    global _FROZEN
    _FROZEN = True


def list_conditions() -> list[str]:
    """In the paper's order."""
    return list(_REGISTRY)


def get_condition(name: str) -> Condition:
    key = name.strip().lower().replace("-", "_")
    key = _ALIASES.get(key, key)
    if key not in _REGISTRY:
        raise ConditionError(f"unknown condition {name!r}; known: {', '.join(_REGISTRY)} "
                             f"(aliases: {', '.join(sorted(_ALIASES))})")
    return _REGISTRY[key]


def resolve_conditions(spec: str | list[str] | None) -> list[Condition]:
    if spec is None or spec == "all" or spec == ["all"]:
        return [get_condition(n) for n in list_conditions()]
    names = spec.split(",") if isinstance(spec, str) else spec
    out = []
    for n in names:
        if n.strip():
            c = get_condition(n)
            if c not in out:
                out.append(c)
    return out


register(Condition("no_memory", "Parametric", "parametric", "none", (), None, aliases=("parametric",),
                   description="No memory: the answer backbone alone."))
register(Condition("flat_1d_raw", "Flat-1D (raw)", "flat1d", "raw", ("search",), "flat1d",
                   description="Chronological text records from the unedited perception stream."))
register(Condition("flat_1d_edited", "Flat-1D (processed)", "flat1d", "edited", ("search",), "flat1d",
                   aliases=("flat_1d_processed",), description="The same records after online editing."))
register(Condition("graph_2d_raw", "Graph-2D (raw)", "graph2d", "raw", GRAPH_TOOLS, "graph2d",
                   description="Entity-relation graph of the unedited stream."))
register(Condition("graph_2d_edited", "Graph-2D (processed)", "graph2d", "edited", GRAPH_TOOLS, "graph2d",
                   aliases=("graph_2d_processed",), description="The graph rebuilt after online editing."))
register(Condition("memora_episodic", "MEMORA-Episodic", "memora_episodic", "episodic", MEMORA_EPISODIC_TOOLS, "memora",
                   description="Typed environment, entity and activity stores; no consolidation."))
register(Condition("memora_full", "MEMORA", "memora", "edited", MEMORA_FULL_TOOLS, "memora", aliases=("memora",),
                   description="All four typed stores: episodic plus routines and preferences."))
freeze()
