"""MEMORA and MEMORA-Episodic read the bank through the typed retrieval tools of
`memora_graph.retrieve` (search, search_objects, get_object_history, get_state_at_time,
search_activities, search_patterns, get_routine_skill, get_preferences). This module only binds
them to one participant for the agent loop; it does not implement any tool."""

from __future__ import annotations

from typing import Any

from memora_graph.errors import MemoraError


def open_memora_tools(banks, participant: str, tools: tuple[str, ...], *, episodic: bool):
    try:
        import memora_graph.retrieve as retrieve
    except ImportError as exc:  # pragma: no cover - the package ships with the project
        raise MemoraError(f"the MEMORA retrieval tools are not installed ({exc})") from None
    if not hasattr(retrieve, "tool_schemas"):
        raise MemoraError("the MEMORA retrieval tools (memora_graph.retrieve) are not available in this checkout yet")
    raise MemoraError("MEMORA tool binding not wired yet")
