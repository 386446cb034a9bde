"""The ReAct agent over the memory tools: tool-call parsing (this package's `toolcalls`)."""

from memora_graph.agent.toolcalls import (
    MAX_CALLS_PER_RESPONSE,
    ToolCall,
    canonical_arguments,
    parse_tool_calls,
    strip_tool_markup,
)

__all__ = [
    "MAX_CALLS_PER_RESPONSE", "ToolCall", "canonical_arguments", "parse_tool_calls",
    "strip_tool_markup",
]
