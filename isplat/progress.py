"""Progress bars on stderr, off when stderr is not a terminal or when the user asked for quiet."""

from __future__ import annotations

import os
import sys

from tqdm import tqdm

_QUIET = False


def set_quiet(quiet: bool) -> None:
    """Switch every progress bar of this process off (``--quiet``)."""
    global _QUIET
    _QUIET = bool(quiet)


def quiet() -> bool:
    """True when --quiet was given."""
    return _QUIET


def enabled() -> bool:
    """True when bars should be shown: not quiet, stderr is a terminal, ISPLAT_PROGRESS not 0."""
    if _QUIET or os.environ.get("ISPLAT_PROGRESS", "") == "0":
        return False
    return sys.stderr.isatty()


def bar(iterable=None, **kwargs):
    """A tqdm bar on stderr that is disabled when :func:`enabled` is false."""
    kwargs.setdefault("leave", False)
    kwargs.setdefault("dynamic_ncols", True)
    kwargs["disable"] = kwargs.get("disable", False) or not enabled()
    return tqdm(iterable, file=sys.stderr, **kwargs)


def log(message: str) -> None:
    """One log line on stderr (suppressed by --quiet)."""
    if not _QUIET:
        print(message, file=sys.stderr)
