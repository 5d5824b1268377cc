"""Helpers shared by the tests and the benchmarks: media generators, the daemon as a real process,
the reliability invariants, and the scenario drivers a bench times and a test checks small.

Imported by `tests/` and `bench/` only (import-linter: never the other way, never by ppd's own
packages); not in the wheel (pyproject's package discovery lists daemon, poisoner, verifier).
"""
