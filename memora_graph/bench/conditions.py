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
Tools are opened per (condition, participant): a tool set is bound to one participant's memory
and drops any argument its schema does not declare, so no call can reach another participant.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from memora_graph.errors import MemoraError


class ConditionError(MemoraError):
    pass


@dataclass(frozen=True)
class Condition:
    name: str
    label: str
    family: str  # prompt family (memora_graph.agent.prompts.FAMILIES)
    bank: str  # which bank the representation is built from: none | raw | edited | episodic
    tools: tuple[str, ...]
    open_tools: Callable[[BankSet, str], Any] | None  # (banks, participant) -> ToolSet; None for Parametric
    aliases: tuple[str, ...] = ()
    description: str = ""


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


# -- tool sets ------------------------------------------------------------------------------------


def _fn(name: str, description: str, properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {"type": "function", "function": {"name": name, "description": description, "parameters": {
        "type": "object", "properties": properties, "required": required}}}


BASELINE_SCHEMAS = {
    "flat_search": _fn("search", "Search the person's chronological text memory; returns the most similar "
                       "time-stamped records.", {"query": {"type": "string"}, "top_k": {"type": "integer"}}, ["query"]),
    "graph_search": _fn("search", "Search the entity-relation graph: embedding seeds plus their one-hop "
                        "neighbours; at most 3 activities, objects, places and patterns.",
                        {"query": {"type": "string"}, "top_k_per_category": {"type": "integer"}}, ["query"]),
    "get_object_history": _fn("get_object_history", "An object's records and the activities it was used in, in "
                              "time order.", {"object_query": {"type": "string"}}, ["object_query"]),
    "get_state_at_time": _fn("get_state_at_time", "What was happening at a time (seconds into a video), with the "
                             "objects seen then.", {"time_seconds": {"type": "number"}, "video_id": {"type": "string"}},
                             ["time_seconds"]),
}


class MethodToolSet:
    """Tools as bound methods of one participant's memory object, with their OpenAI schemas."""

    def __init__(self, participant: str, memory: Any, schemas: dict[str, dict[str, Any]]):
        self.participant = participant
        self.memory = memory
        self._schemas = schemas

    def schemas(self) -> list[dict[str, Any]]:
        return list(self._schemas.values())

    def prefetch(self, calls: list[tuple[str, dict[str, Any]]]) -> None:
        """Embed the query texts of one response's calls in one batch (the baselines embed
        queries through the process-wide cache, so their calls then find them there)."""
        from memora_graph.bench.memora_tools import query_texts
        from memora_graph.embed import get_embedder
        from memora_graph.retrieve.embedding import torch_threads

        texts = list(dict.fromkeys(query_texts(calls)))
        if texts:
            with torch_threads(1):
                get_embedder().encode(texts, kind="query")

    def call(self, name: str, arguments: dict[str, Any]) -> Any:
        if name not in self._schemas:
            return {"error": f"unknown tool {name!r}; available: {', '.join(self._schemas)}"}
        allowed = self._schemas[name]["function"]["parameters"]["properties"]
        args = {k: v for k, v in arguments.items() if k in allowed}
        missing = [k for k in self._schemas[name]["function"]["parameters"]["required"] if k not in args]
        if missing:
            return {"error": f"{name}: missing argument(s) {', '.join(missing)}"}
        return getattr(self.memory, name)(**args)


def _open_flat(kind: str):
    def opener(banks: BankSet, participant: str) -> MethodToolSet:
        from memora_graph.baselines.flat1d import Flat1DMemory

        path = banks.path(kind)
        memory = banks.memory(f"flat1d:{kind}", participant, lambda: Flat1DMemory.load(path, participant))
        return MethodToolSet(participant, memory, {"search": BASELINE_SCHEMAS["flat_search"]})
    return opener


def _open_graph(kind: str):
    def opener(banks: BankSet, participant: str) -> MethodToolSet:
        from memora_graph.baselines.graph2d import Graph2DMemory

        path = banks.path(kind)
        memory = banks.memory(f"graph2d:{kind}", participant, lambda: Graph2DMemory.load(path, participant))
        return MethodToolSet(participant, memory, {
            "search": BASELINE_SCHEMAS["graph_search"],
            "get_object_history": BASELINE_SCHEMAS["get_object_history"],
            "get_state_at_time": BASELINE_SCHEMAS["get_state_at_time"],
        })
    return opener


MEMORA_EPISODIC_TOOLS = ("search", "search_objects", "get_object_history", "get_state_at_time", "search_activities",
                         "search_patterns")
MEMORA_FULL_TOOLS = MEMORA_EPISODIC_TOOLS + ("get_routine_skill", "get_preferences")


def _open_memora(tools: tuple[str, ...], episodic: bool):
    def opener(banks: BankSet, participant: str):
        from memora_graph.bench.memora_tools import open_memora_tools

        return open_memora_tools(banks, participant, tools, episodic=episodic)
    return opener


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
register(Condition("flat_1d_raw", "Flat-1D (raw)", "flat1d", "raw", ("search",), _open_flat("raw"),
                   description="Chronological text records from the unedited perception stream."))
register(Condition("flat_1d_edited", "Flat-1D (processed)", "flat1d", "edited", ("search",), _open_flat("edited"),
                   aliases=("flat_1d_processed",), description="The same records after online editing."))
register(Condition("graph_2d_raw", "Graph-2D (raw)", "graph2d", "raw",
                   ("search", "get_object_history", "get_state_at_time"), _open_graph("raw"),
                   description="Entity-relation graph of the unedited stream."))
register(Condition("graph_2d_edited", "Graph-2D (processed)", "graph2d", "edited",
                   ("search", "get_object_history", "get_state_at_time"), _open_graph("edited"),
                   aliases=("graph_2d_processed",), description="The graph rebuilt after online editing."))
register(Condition("memora_episodic", "MEMORA-Episodic", "memora_episodic", "episodic", MEMORA_EPISODIC_TOOLS,
                   _open_memora(MEMORA_EPISODIC_TOOLS, episodic=True),
                   description="Typed environment, entity and activity stores; no consolidation."))
register(Condition("memora_full", "MEMORA", "memora", "edited", MEMORA_FULL_TOOLS,
                   _open_memora(MEMORA_FULL_TOOLS, episodic=False), aliases=("memora",),
                   description="All four typed stores: episodic plus routines and preferences."))
freeze()
