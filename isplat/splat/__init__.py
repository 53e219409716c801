"""Splatting: footprint tables (footprint.py) and the compiled kernels (kernels.py)."""
