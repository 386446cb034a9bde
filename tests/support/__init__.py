"""Test support shared by the test modules (import as `support.*`; pytest puts tests/ on sys.path)."""
