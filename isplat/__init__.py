"""isplat: fast, exact direct volume rendering by indexed splatting (Ihm & Lee).

Each stage is a plain function first and a command second:

>>> import isplat
>>> isplat.augment.augment_file("head.npy", "head.aug.h5")          # doctest: +SKIP
>>> isplat.index.build_index_file("head.aug.h5", "head.idx.h5")      # doctest: +SKIP
"""

__version__ = "0.1.0"
