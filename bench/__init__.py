"""Benchmarks (not tests): ``python -m bench [NAME ...]`` writes sections of BENCHMARKS.md."""
