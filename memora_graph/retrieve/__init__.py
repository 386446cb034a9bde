"""Memory-guided retrieval: the MEMORA tools over one participant's memory bank.

    from memora_graph.retrieve import MemoryView, call_tool, tool_schemas
    with MemoryView.open("banks/epic", "P03") as view:
        result = call_tool(view, "get_routine_skill", {"goal_query": "wash the bowl"})
    result.routines[0].goal                      # typed results (memora_graph.retrieve.results)
    schemas = tool_schemas()          # OpenAI function schemas for an agent's `tools=[...]`
"""

from memora_graph.retrieve import tools as _tools  # noqa: F401  (registers the MEMORA tools)
from memora_graph.retrieve.registry import (
    Family, Reply, ToolSet, ToolSpec, call_tool, families, first_arguments, get_family, get_tool, register,
    register_family, specs, store_of, tool, tool_names, tool_schemas, tool_set, unregister,
)
from memora_graph.retrieve.results import ToolErrorResult, ToolResult
from memora_graph.retrieve.search import DEFAULT_TOP_K, MAX_TOP_K, RECIPES, SearchConfig
from memora_graph.retrieve.tools import (
    get_object_history, get_preferences, get_routine_skill, get_state_at_time, search, search_activities,
    search_environment, search_objects, search_patterns,
)
from memora_graph.retrieve.view import MemoryView, ToolError

__all__ = [
    "DEFAULT_TOP_K", "MAX_TOP_K", "RECIPES", "Family", "MemoryView", "Reply", "SearchConfig", "ToolError", "ToolErrorResult",
    "ToolResult", "ToolSet", "ToolSpec", "call_tool", "families", "first_arguments", "get_family",
    "get_object_history", "get_preferences", "get_routine_skill", "get_state_at_time", "get_tool", "register",
    "register_family", "search", "search_activities", "search_environment", "search_objects", "search_patterns",
    "specs", "store_of", "tool", "tool_names", "tool_schemas", "tool_set", "unregister",
]
