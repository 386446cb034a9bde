"""Test and benchmark helpers that ship with the library: the scripted OpenAI-compatible server,
its request-driven responders, and the real-model check."""
