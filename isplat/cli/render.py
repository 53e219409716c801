"""isplat render: images from a TOML scene."""

from __future__ import annotations

import contextlib
import json
import logging
import sys
from pathlib import Path

import click

from .. import progress
from .options import force_option, quiet_option, verbose_option

log = logging.getLogger(__name__)


@click.command("render")
@click.argument("scene_file", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", default=None, metavar="OUT",
              help="Image file: .png (8/16-bit per image.bit_depth), .tif/.tiff (float), '-' for PNG on "
                   "stdout; for a batch of views numbered files (NAME_000.png, or a {n} / %03d pattern), "
                   ".gif or .mp4. Default: SCENE's name with .png (or .gif for a batch) in the current folder.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a scene key, e.g. --set camera.azimuth=45 --set render.method=full (repeatable).")
@click.option("--view", "view", type=int, default=None, metavar="N",
              help="Render only view N (0-based) of the scene's batch of views.")
@click.option("--scheduler", default=None, metavar="local:N|tcp://HOST:PORT",
              help="Render on Dask (the 'dask' extra): local:N starts N single-threaded worker processes here, "
                   "tcp://HOST:PORT uses a running cluster whose workers see the scene's files. Frames are the "
                   "same as without it. See docs/scale.md.")
@click.option("--slabs", type=click.IntRange(1, 4096), default=None, metavar="K",
              help="Split each frame's slices into K slabs: with --scheduler rendered on different workers and "
                   "composited in order; without it rendered front to back here, one slab's selection in memory at "
                   "a time (the same image). Default: 1, or without --scheduler as many as a selection too large "
                   "for the memory left needs (said on stderr).")
@verbose_option("Report on stderr what was read (bytes, channels, axes) and per-view timing and voxel "
                "counts (same as isplat -v).")
@click.option("--json", "as_json", is_flag=True, help="Print that report as one JSON object on stdout "
                                                      "(not with -o -).")
@force_option
@quiet_option
def render(scene_file, out, overrides, view, as_json, force, scheduler, slabs):
    """Render SCENE (a TOML file, see formats/scene.md) to images.

    Only what the scene needs is read: the index axes its views use, the blocks in the transfer
    function's non-zero-opacity density intervals, normals only when shading is on, gradient magnitudes
    only when the transfer function uses them.

    \b
    Examples:
      isplat render examples/head.toml -o head.png
      isplat render head.toml --set camera.azimuth=90 --set render.method=full -o side.png
      isplat render head.toml -o - | display -          # PNG on stdout
      for a in 0 45 90; do isplat render head.toml --set camera.azimuth=$a -o head_$a.png; done
      isplat render orbit.toml -o orbit.gif              # a batch of views as an animated GIF
    """
    from ..errors import IsplatError
    from ..output import (check_format, check_memory, check_outputs, frame_paths, output_buffer_bytes, write_movie,
                          write_still)
    from ..threads import default_threads
    from ..scene import load_scene

    scene = load_scene(scene_file, list(overrides))
    views = scene.views
    if view is not None:
        if not 0 <= view < len(views):
            raise IsplatError(f"--view {view}: the scene has {len(views)} view(s) (0..{len(views) - 1})")
        views = (views[view],)
    batch = len(views) > 1
    if out is None:
        out = Path(scene_file).stem + (".gif" if batch else ".png")
    if as_json and out == "-":
        raise IsplatError("--json and -o - both want stdout; choose one")
    ext = check_format(out, batch)
    if out == "-" and sys.stdout.isatty():
        raise IsplatError("-o -: standard output is a terminal, not a place for PNG bytes; redirect it "
                          "(-o - > image.png) or pipe it (-o - | display -)")
    movie = ext in (".gif", ".mp4")
    itemsize = 8 if scene.render.precision == "float64" else 4
    check_memory(output_buffer_bytes(scene.image.width, scene.image.height, len(views), movie, ext, itemsize,
                                     scene.render.threads or default_threads(), scene.render.supersample),
                 f"{scene.image.width}x{scene.image.height}" + (f", {len(views)} views" if movie else ""))
    paths = [] if out == "-" else ([Path(out)] if movie else frame_paths(out, len(views)))
    check_outputs(paths, force)

    frames, per_view, rep = [], [], None
    with _frames(scene, views, scheduler, slabs) as (method, results, held):
        for n, rgba, st, rep in results:
            per_view.append({"view": n if view is None else view, "axis": ("+" if st.sign > 0 else "-") + st.axis,
                             "voxels_examined": st.voxels_examined, "classification": st.classification,
                             "voxels_splatted" if st.classification == "pre" else "samples": st.voxels_splatted,
                             "slices": st.slices, "seconds": round(st.seconds, 6)})
            if movie:
                frames.append(rgba)
            else:
                write_still(out if out == "-" else str(paths[n]), rgba, scene.image.bit_depth, force)
    if movie:
        write_movie(out, frames, force, fps=scene.fps)
    report = {"scene": str(scene_file), "method": method, "output": out,
              "axes_loaded": rep.axes, "channels_loaded": rep.channels, "intervals": rep.intervals,
              "augmented_bytes_read": rep.augmented_bytes, "index_bytes_read": rep.index_bytes,
              "file_bytes_read": rep.file_bytes, "bytes_needed": rep.bytes_needed, "values_from": rep.values_from,
              "views": per_view}
    if as_json:
        json.dump(report, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    log.debug(f"read: {rep.augmented_bytes} bytes of augmented channels {rep.channels or '(none)'}; "
              f"{rep.index_bytes} bytes of index axes {rep.axes or '(none)'} for density intervals {rep.intervals}; "
              f"{rep.file_bytes} bytes read from the files (HDF5 chunks and metadata) for {rep.bytes_needed} needed "
              f"({rep.read_ratio:.2f}x); channel values from {rep.values_from}" + (
                  f"; held {held()} bytes, {held() / max(1, rep.voxels_of_interest):.2f} per voxel of interest"
                  if held else " (selections held by the workers or one slab at a time)"))
    for v in per_view:
        drawn = f"{v['voxels_splatted']} splatted" if "voxels_splatted" in v else f"{v['samples']} samples composited"
        log.debug(f"view {v['view']}: axis {v['axis']}, {v['voxels_examined']} voxels examined, {drawn} "
                  f"({v['classification']}-classified), {v['seconds'] * 1000:.1f} ms")


@contextlib.contextmanager
def _frames(scene, views, scheduler, slabs):
    """(method, iterator of (n, rgba, FrameStats, LoadReport) in view order, the held bytes' function or None):
    in this process, in slabs here, or on Dask."""
    from ..renderer import Renderer

    if scheduler is None and slabs is None:
        slabs = _auto_slabs(scene, views)
    slabs = slabs or 1
    bar = progress.bar(total=len(views), desc="views", unit="view")
    with bar:
        if scheduler is None and slabs > 1:
            yield scene.render.method, _streamed(scene, views, slabs, bar), None
            return
        if scheduler is None:
            renderer = Renderer(scene, views)

            def local():
                for n in range(len(views)):
                    rgba, st = renderer.render_view(n)
                    bar.update(1)
                    yield n, rgba, st, renderer.report
            yield renderer.method, local(), renderer.held_bytes
            return
        from .. import distributed
        from ..augfile import open_augmented
        from ..frame import views_for

        with distributed.connect(scheduler) as client:
            vs = views_for(scene, open_augmented(scene.data.augmented), views)
            yield scene.render.method, distributed.render_views(client, scene, vs, slabs=slabs, bar=bar), None


def _auto_slabs(scene, views) -> int:
    """The slabs a frame needs to fit in the memory left (isplat.slabs.slabs_needed); 1 when it fits."""
    from ..augfile import open_augmented
    from ..frame import views_for
    from ..slabs import PEAK_PER_VOXEL, memory_room, slabs_needed

    room = memory_room()
    if room is None or scene.render.method != "indexed":
        return 1
    aug = open_augmented(scene.data.augmented)
    k, voxels = slabs_needed(scene, views_for(scene, aug, views), aug, room)
    if k > 1:
        log.info(f"isplat render: the selection ({voxels:,} voxels of interest, about "
                 f"{voxels * PEAK_PER_VOXEL / 2**30:.2f} GiB while it is made) does not fit the "
                 f"{room / 2**30:.2f} GiB of memory left: each frame in {k} slabs front to back (--slabs {k})")
    return k


def _streamed(scene, views, slabs, bar):
    """Each view front to back in ``slabs`` slabs, one slab's selection at a time (isplat.slabs.render_streamed)."""
    from ..augfile import open_augmented
    from ..frame import views_for
    from ..slabs import render_streamed

    aug = open_augmented(scene.data.augmented)
    for n, view in enumerate(views_for(scene, aug, views)):
        rgba, st, report = render_streamed(scene, view, slabs, aug)
        bar.update(1)
        yield n, rgba, st, report
