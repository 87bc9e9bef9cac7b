"""Vectorised NumPy twins of every kernel: the tests' oracle and the benchmark baseline."""
