"""Memory-guided retrieval: the MEMORA tools over one participant's memory bank.

    from memora_graph.retrieve import MemoryView, call_tool, tool_schemas
    with MemoryView.open("banks/epic", "P03") as view:
        result = call_tool(view, "get_routine_skill", {"goal_query": "wash the bowl"})
    schemas = tool_schemas()          # OpenAI function schemas for an agent's `tools=[...]`
"""

from memora_graph.retrieve.registry import ToolSpec, call_tool, get_tool, register, tool_names, tool_schemas
from memora_graph.retrieve.search import DEFAULT_TOP_K, MAX_TOP_K, RECIPES, SearchConfig
from memora_graph.retrieve.tools import (
    get_object_history, get_preferences, get_routine_skill, get_state_at_time, search, search_activities,
    search_environment, search_objects, search_patterns,
)
from memora_graph.retrieve.view import MemoryView, ToolError

__all__ = [
    "DEFAULT_TOP_K", "MAX_TOP_K", "RECIPES", "MemoryView", "SearchConfig", "ToolError", "ToolSpec", "call_tool",
    "get_object_history", "get_preferences", "get_routine_skill", "get_state_at_time", "get_tool", "register",
    "search", "search_activities", "search_environment", "search_objects", "search_patterns", "tool_names",
    "tool_schemas",
]
