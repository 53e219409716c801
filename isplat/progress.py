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

LOGGER = logging.getLogger("isplat")


def enabled() -> bool:
    """True when bars should be shown: the ``isplat`` logger lets INFO through (not ``-q``), stderr is a
    terminal and ISPLAT_PROGRESS is not 0."""
    if not LOGGER.isEnabledFor(logging.INFO) or os.environ.get("ISPLAT_PROGRESS", "") == "0":
        return False
    return sys.stderr.isatty()


class _NoBar:
    """What :func:`bar` returns when no bar is shown: iterates, updates and closes like a disabled tqdm bar,
    without importing tqdm (30 ms of a one-frame ``isplat render -q``)."""

    def __init__(self, iterable=None):
        self.iterable = iterable

    def __iter__(self):
        return iter(self.iterable)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n=1):
        pass

    def close(self):
        pass


def bar(iterable=None, **kwargs):
    """A tqdm bar on stderr; when :func:`enabled` is false (or ``disable``) one that shows nothing."""
    if kwargs.pop("disable", False) or not enabled():
        return _NoBar(iterable)
    from tqdm import tqdm

    kwargs.setdefault("leave", False)
    kwargs.setdefault("dynamic_ncols", True)
    return tqdm(iterable, file=sys.stderr, **kwargs)
