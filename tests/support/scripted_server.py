"""The scripted OpenAI-compatible server lives in the package (a benchmark uses it too)."""

from memora_graph.testing.scripted_server import ScriptedServer, Turn, tool_call  # noqa: F401
