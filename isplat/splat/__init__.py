"""Splatting: footprint tables (footprint.py), the traversal every technique shares (traverse.py) and the
techniques (pre.py, post.py, sheets.py)."""
