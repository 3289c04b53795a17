"""Reproducible benchmarks run by ``curio bench NAME``; see docs/benchmarks.md."""
