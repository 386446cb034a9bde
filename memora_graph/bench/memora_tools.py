"""MEMORA and MEMORA-Episodic read the bank through the typed retrieval tools of
`memora_graph.retrieve`; this module only binds them to one participant for the agent loop.

MEMORA (memora_full) reads the consolidated bank (the default `memora build`) and advertises
get_routine_skill and get_preferences. MEMORA-Episodic reads a bank built with
`memora build DIR --episodic` (no routines or preferences at all, so no tool can surface them)
and does not advertise those two tools.
"""

from __future__ import annotations

from typing import Any

from memora_graph.retrieve import MemoryView, ToolError, call_tool, tool_schemas

QUERY_ARGUMENTS = ("query", "goal_query", "object_query", "goal", "object", "name")


def query_texts(calls: list[tuple[str, dict[str, Any]]]) -> list[str]:
    """The free-text arguments of a batch of tool calls, the ones a tool embeds."""
    return [v for _, args in calls for k, v in args.items() if k in QUERY_ARGUMENTS and isinstance(v, str)]


class MemoraToolSet:
    def __init__(self, view: MemoryView, names: tuple[str, ...]):
        self.participant = view.participant
        self.view = view
        self.names = names
        self._schemas = tool_schemas(list(names))

    def schemas(self) -> list[dict[str, Any]]:
        return self._schemas

    def prefetch(self, calls: list[tuple[str, dict[str, Any]]]) -> None:
        """Embed the query texts of one response's calls in one batch before they run."""
        self.view.encoder.prefetch(query_texts(calls))

    def call(self, name: str, arguments: dict[str, Any]) -> Any:
        if name not in self.names:
            return {"error": f"unknown tool {name!r}; available: {', '.join(self.names)}"}
        allowed = set(self._schemas[self.names.index(name)]["function"]["parameters"]["properties"])
        # aliases the registry accepts (search_objects(name=...), get_routine_skill(goal=...)) pass through
        aliases = {"name", "object", "query", "goal"}
        args = {k: v for k, v in arguments.items() if k in allowed or k in aliases}
        try:
            return call_tool(self.view, name, args)
        except ToolError as exc:
            return {"error": str(exc)}

    def close(self) -> None:
        self.view.close()


def open_memora_tools(banks, participant: str, tools: tuple[str, ...], *, episodic: bool) -> MemoraToolSet:
    kind = "episodic" if episodic else "edited"
    path = banks.path(kind)
    view = banks.memory(f"memora:{kind}", participant, lambda: MemoryView.open(path, participant))
    return MemoraToolSet(view, tools)
