"""`memora serve`: a memory bank as a Model Context Protocol server.

    from memora_graph.serve import MemoryService
    with MemoryService("banks/epic", participant="P03") as service:
        service.call("get_routine_skill", {"goal_query": "wash the bowl"})     # the tool's JSON result

`service` holds the bank and the served tools (no MCP in it); `app` puts a service on the wire
over stdio or streamable HTTP with the official `mcp` SDK; `perf` times warm calls over HTTP.
"""

from memora_graph.serve.service import ArgumentError, Endpoint, MemoryService, UnknownTool

__all__ = ["ArgumentError", "Endpoint", "MemoryService", "UnknownTool"]
