"""Solver plumbing shared by the kernels and the product: constants and the SIMD lane width (settings.py)."""
