"""Safe output files: checked up front, written under a temporary name, renamed on success.

A failed run leaves nothing behind, and nothing the user had is overwritten without ``force``.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from .errors import IsplatError


def check_input(path: str | os.PathLike, what: str = "input") -> Path:
    """Return ``path`` as a Path if it is a readable file, else raise a one-line error."""
    p = Path(path)
    if not p.exists():
        raise IsplatError(f"{p}: {what} file does not exist")
    if p.is_dir():
        raise IsplatError(f"{p}: {what} is a folder, expected a file")
    if not os.access(p, os.R_OK):
        raise IsplatError(f"{p}: {what} file is not readable")
    return p


def check_output(path: str | os.PathLike, force: bool = False) -> Path:
    """Check that ``path`` may be written: its folder exists and it does not exist unless ``force``."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise IsplatError(f"{p}: output folder {parent} does not exist")
    if not parent.is_dir():
        raise IsplatError(f"{p}: {parent} is not a folder")
    if p.is_dir():
        raise IsplatError(f"{p}: output is a folder, expected a file name")
    if p.exists() and not force:
        raise IsplatError(f"{p}: output exists; use --force to overwrite")
    return p


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, force: bool = False):
    """Yield a temporary path beside ``path``; rename it to ``path`` only if the block succeeds.

    >>> with atomic_output("out.h5", force=True) as tmp:   # doctest: +SKIP
    ...     write_everything(tmp)
    """
    p = check_output(path, force)
    parent = p.parent if str(p.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".part", dir=parent)
    os.close(fd)
    # mkstemp makes the file owner-only; give it the mode an ordinary new file would get
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield Path(tmp)
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def open_hdf5(path, what: str, format_name: str, version: int):
    """Open an isplat HDF5 container read-only after checking its ``format`` and ``format_version``
    attributes; return ``(path, h5py.File)``. Every problem is one :class:`IsplatError` line."""
    import h5py
    import numpy as np

    p = check_input(path, what)
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise IsplatError(f"{p}: not a readable HDF5 file ({exc.__class__.__name__}: truncated or not HDF5)") from None
    fmt = f.attrs.get("format")
    if isinstance(fmt, bytes):
        fmt = fmt.decode(errors="replace")
    ver = f.attrs.get("format_version")
    try:
        ver_ok = ver is not None and np.ndim(ver) == 0 and int(ver) == version
    except (TypeError, ValueError):
        ver_ok = False
    if fmt != format_name:
        f.close()
        raise IsplatError(f"{p}: attribute 'format' is {fmt!r}, expected {format_name!r}")
    if not ver_ok:
        f.close()
        raise IsplatError(f"{p}: attribute 'format_version' is {ver!r}, this isplat reads version {version}")
    return p, f
