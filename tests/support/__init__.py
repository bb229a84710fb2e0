"""Helpers shared by several test modules (importable: ``tests`` is on the test path)."""
