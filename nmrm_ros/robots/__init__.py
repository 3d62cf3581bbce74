"""Fake robots for tests and the docs (a unicycle delivery task)."""
