"""The scripted OpenAI-compatible server lives in the library (memora_graph/testing/scripted_server.py),
where `memora perf model` uses it too; the tests import it from here as before."""

from memora_graph.testing.scripted_server import ScriptedServer, Turn, tool_call  # noqa: F401

__all__ = ["ScriptedServer", "Turn", "tool_call"]
