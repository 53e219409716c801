"""Writing rendered images: PNG (8/16-bit), float TIFF, PNG on stdout, numbered batches, GIF/MP4."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

import numpy as np

from .errors import IsplatError
from .fileio import atomic_output, check_output

STILL = {".png", ".tif", ".tiff"}
MOVIE = {".gif", ".mp4"}


def to_pixels(rgba: np.ndarray, fmt: str, bit_depth: int = 8) -> np.ndarray:
    """Straight RGBA float in [0,1] -> the array written for ``fmt`` (alpha dropped when opaque)."""
    arr = rgba if np.any(rgba[..., 3] < 1.0) else rgba[..., :3]
    if fmt in (".tif", ".tiff"):
        return np.ascontiguousarray(arr, dtype=np.float32)
    if fmt == ".png" and bit_depth == 16:
        return np.round(np.clip(arr, 0, 1) * 65535.0).astype(np.uint16)
    return np.round(np.clip(arr, 0, 1) * 255.0).astype(np.uint8)


def frame_paths(out: str, n: int) -> list[Path]:
    """Names for ``n`` frames: ``{n}``/``%03d`` patterns are filled in, else ``name_000.ext``."""
    if n == 1:
        return [Path(out)]
    if "{n" in out:
        return [Path(out.format(n=i)) for i in range(n)]
    if re.search(r"%0?\d*d", out):
        return [Path(out % i) for i in range(n)]
    p = Path(out)
    width = max(3, len(str(n - 1)))
    return [p.with_name(f"{p.stem}_{i:0{width}d}{p.suffix}") for i in range(n)]


def check_format(out: str, batch: bool) -> str:
    """Validate the output name up front; returns its extension."""
    if out == "-":
        if batch:
            raise IsplatError("-o -: standard output takes one image; pick a view with --view N or name a file")
        return ".png"
    ext = Path(out).suffix.lower()
    if ext not in STILL | MOVIE:
        raise IsplatError(f"{out}: unknown image type {ext or '(none)'!r}; expected .png, .tif, .tiff, .gif or .mp4")
    if ext == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise IsplatError(f"{out}: writing .mp4 needs imageio-ffmpeg: pip install 'isplat[mp4]'; "
                              "or write .gif or numbered .png frames") from None
    return ext


def png_bytes(pixels: np.ndarray) -> bytes:
    """Encode 8- or 16-bit grey/RGB/RGBA pixels as PNG (pypng: Pillow cannot write 16-bit colour)."""
    import io

    import png

    h, w = pixels.shape[:2]
    planes = 1 if pixels.ndim == 2 else pixels.shape[2]
    buf = io.BytesIO()
    png.Writer(w, h, greyscale=planes < 3, alpha=planes in (2, 4),
               bitdepth=16 if pixels.dtype == np.uint16 else 8).write(buf, pixels.reshape(h, w * planes))
    return buf.getvalue()


def write_still(out: str, rgba: np.ndarray, bit_depth: int, force: bool) -> None:
    """Write one image atomically, or PNG bytes to stdout for ``-o -``."""
    if out == "-":
        sys.stdout.buffer.write(png_bytes(to_pixels(rgba, ".png", bit_depth)))
        sys.stdout.buffer.flush()
        return
    ext = Path(out).suffix.lower()
    with atomic_output(out, force) as tmp:
        if ext == ".png":            # pypng: imageio takes a quarter second to import, a PNG does not need it
            Path(tmp).write_bytes(png_bytes(to_pixels(rgba, ext, bit_depth)))
        else:
            import imageio.v3 as iio

            iio.imwrite(tmp, to_pixels(rgba, ext, bit_depth), extension=ext)


def write_movie(out: str, frames: list[np.ndarray], force: bool, fps: float = 12.0) -> None:
    """Write an animated GIF (or MP4) of straight-RGBA frames atomically."""
    import imageio.v3 as iio

    ext = Path(out).suffix.lower()
    px = [to_pixels(f, ".png", 8)[..., :3] for f in frames]
    with atomic_output(out, force) as tmp:
        if ext == ".gif":
            iio.imwrite(tmp, np.stack(px), extension=".gif", duration=1000.0 / fps, loop=0)
        else:  # the temporary name does not end in .mp4, so ffmpeg is told the container
            iio.imwrite(tmp, np.stack(px), extension=".mp4", fps=fps, output_params=["-f", "mp4"])


def check_outputs(paths, force: bool) -> None:
    """:func:`isplat.fileio.check_output` for each path, each folder probed once."""
    probed = set()
    for p in paths:
        folder = os.path.abspath(os.path.dirname(p) or ".")
        check_output(p, force, probe=folder not in probed)
        probed.add(folder)


def memory_available() -> int | None:
    """Bytes this machine can still give (``MemAvailable`` of /proc/meminfo, else free pages), or None."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def output_buffer_bytes(width: int, height: int, n_views: int, movie: bool, ext: str, itemsize: int,
                        threads: int, supersample: int = 1) -> int:
    """Bytes of the image buffers a render allocates: image and sheet (RGBA, ``itemsize``), the composited
    copy, saturation masks, one touched-pixel list (int64) per thread (all at ``supersample`` times the width
    and height), the pixels written (float32 RGBA for TIFF), and for a movie every frame kept until the file is
    written, plus their 8-bit stack."""
    px = int(width) * int(height)
    frame = px * 4 * itemsize
    fine = px * int(supersample) ** 2
    work = 3 * fine * 4 * itemsize + 2 * fine + max(1, threads) * (fine + 1) * 8
    written = px * 4 * (4 if ext in (".tif", ".tiff") else 2)
    if movie:
        return work + int(n_views) * (frame + 2 * px * 3)
    return work + written


def check_memory(needed: int, what: str) -> None:
    """Refuse, before allocating, buffers larger than the memory available."""
    avail = memory_available()
    if avail is not None and needed > avail:
        raise IsplatError(f"{what} needs {needed / 2**30:.2f} GiB of image buffers, {avail / 2**30:.2f} GiB of "
                          f"memory is available; make the image smaller, use fewer views, or free memory")
