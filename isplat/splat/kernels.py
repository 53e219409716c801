"""Where the frame kernel's names used to live, kept for the code that imports them from here.

The kernel is now cut in two (docs/design.md, "The kernels' structure"): :mod:`isplat.splat.traverse`, the
traversal every technique shares (the layouts, the band and slice loop, the region -> block -> cell walk and the
occlusion tests), and one module per technique: :mod:`isplat.splat.pre` (the paper's splatting),
:mod:`isplat.splat.post` (post-classification) and :mod:`isplat.splat.sheets` (image-aligned sheets). New code
imports from those.
"""

from .traverse import Bands, Bins, Buffers, IndexedVoxels, SliceGeometry, WholeVolume  # noqa: F401
