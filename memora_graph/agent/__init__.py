"""The ReAct agent over the memory tools: tool-call parsing (this package's `toolcalls`)."""

from memora_graph.agent.toolcalls import (
    FIRST_PARAMETER,
    MAX_CALLS_PER_RESPONSE,
    ToolCall,
    canonical_arguments,
    parse_tool_calls,
    strip_tool_markup,
)

__all__ = [
    "FIRST_PARAMETER", "MAX_CALLS_PER_RESPONSE", "ToolCall", "canonical_arguments", "parse_tool_calls",
    "strip_tool_markup",
]
