"""Helpers the tests share: import them as ``from support.<module> import ...`` (pytest puts ``tests/`` on the path)."""
