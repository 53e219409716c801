"""Progress bars on stderr, shown only while the ``isplat`` logger lets INFO through.

Log lines go through the standard :mod:`logging` module (``logging.getLogger(__name__)`` in each module, all
under the ``isplat`` logger). The command line sets that logger's level from ``-v``/``-q`` (INFO by default);
a program using isplat as a library sees neither log lines nor bars until it configures logging, e.g.
``logging.basicConfig(level=logging.INFO)``.
"""

from __future__ import annotations

import logging
import os
import sys

from tqdm import tqdm

LOGGER = logging.getLogger("isplat")


def enabled() -> bool:
    """True when bars should be shown: the ``isplat`` logger lets INFO through (not ``-q``), stderr is a
    terminal and ISPLAT_PROGRESS is not 0."""
    if not LOGGER.isEnabledFor(logging.INFO) or os.environ.get("ISPLAT_PROGRESS", "") == "0":
        return False
    return sys.stderr.isatty()


def bar(iterable=None, **kwargs):
    """A tqdm bar on stderr that is disabled when :func:`enabled` is false."""
    kwargs.setdefault("leave", False)
    kwargs.setdefault("dynamic_ncols", True)
    kwargs["disable"] = kwargs.get("disable", False) or not enabled()
    return tqdm(iterable, file=sys.stderr, **kwargs)
