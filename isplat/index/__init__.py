"""The three-axis density index of Ihm & Lee §2.1 with the byte encoding of §2.3 (formats/index.md).

Build once per volume (``build_index``/``build_index_file``), then load one axis for the density intervals
of a transfer function (``open_index(path).load_axis(axis, intervals)``).
"""

from .build import (AxisIndex, axis_geometry, build_axis, build_index, escape_width, normalize_ranges,
                    parse_axes, parse_ranges)
from .store import (FORMAT_NAME, FORMAT_VERSION, IndexFile, LoadedAxis, build_index_file, open_index,
                    values_path, write_index)

__all__ = [
    "AxisIndex", "IndexFile", "LoadedAxis", "FORMAT_NAME", "FORMAT_VERSION", "axis_geometry", "build_axis",
    "build_index", "build_index_file", "escape_width", "normalize_ranges", "open_index", "parse_axes",
    "parse_ranges", "values_path", "write_index",
]
