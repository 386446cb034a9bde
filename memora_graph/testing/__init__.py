"""Test and benchmark helpers that ship with the library: the scripted OpenAI-compatible server,
its request-driven responders, synthetic videos and perception replies, and the real-model check."""
