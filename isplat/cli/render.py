"""isplat render: images from a TOML scene, or from an augmented file and a preset (isplat.scene_input)."""

from __future__ import annotations

import contextlib
import json
import logging
import sys
import time
from pathlib import Path

import click

from .. import progress
from .options import force_option, quiet_option, verbose_option

log = logging.getLogger(__name__)


@click.command("render")
@click.argument("scene_file", metavar="SCENE|AUG.h5", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", default=None, metavar="OUT",
              help="Image file: .png (8/16-bit per image.bit_depth), .tif/.tiff (float), '-' for PNG on "
                   "stdout; for a batch of views numbered files (NAME_000.png, or a {n} / %03d pattern), "
                   ".gif or .mp4. Default: SCENE's name with .png (or .gif for a batch) in the current folder.")
@click.option("--preset", default=None, metavar="NAME",
              help="Transfer function preset (isplat presets lists them): the same as --set transfer.preset=NAME.")
@click.option("--index", "index", default=None, metavar="IDX.h5",
              help="The index (--set data.index=IDX.h5). Default for AUG.h5: the one beside it with the same stem "
                   "(ct.aug.h5: ct.idx.h5); without one every voxel is read (render.method = \"full\").")
@click.option("--size", default=None, metavar="N|WxH",
              help="Image size in pixels (image.width, image.height); default for AUG.h5: 512x512.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a scene key, e.g. --set camera.azimuth=45 --set render.method=full (repeatable).")
@click.option("--print-scene", is_flag=True,
              help="Write the scene used, as TOML, on stdout (one that renders the same picture: save it to "
                   "render batches or edit it); nothing is rendered unless -o is given.")
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
def render(scene_file, out, preset, index, size, overrides, print_scene, view, as_json, force, scheduler, slabs):
    """Render SCENE (a TOML file, see formats/scene.md), or an augmented file AUG.h5 with a preset, to images.

    AUG.h5 alone is rendered with the scene defaults (formats/scene.md), a 512x512 image and the index
    beside it; --preset (or --set transfer.*) gives its transfer function. --print-scene writes that scene:
    a scene file is still the way to keep a picture's settings and to render batches.

    Only what the scene needs is read: the index axes its views use, the blocks in the transfer
    function's non-zero-opacity density intervals, normals only when shading is on, gradient magnitudes
    only when the transfer function uses them.

    \b
    Examples:
      isplat render ct.aug.h5 --preset ct-bone -o ct.png
      isplat render ct.aug.h5 --preset ct-skin --set camera.view=left --size 800x600 -o left.png
      isplat render ct.aug.h5 --preset ct-bone --print-scene > ct.toml
      isplat render examples/head.toml -o head.png
      isplat render head.toml --set camera.azimuth=90 --set render.method=full -o side.png
      isplat render head.toml -o - | display -          # PNG on stdout
      for a in 0 45 90; do isplat render head.toml --set camera.azimuth=$a -o head_$a.png; done
      isplat render orbit.toml -o orbit.gif              # a batch of views as an animated GIF
    """
    from ..renderer import Renderer
    from ..scene_input import load_input, output_stem

    t0 = time.perf_counter()
    if print_scene and (out == "-" or as_json):
        raise _error(f"--print-scene and {'-o -' if out == '-' else '--json'} both want stdout; choose one")
    opened = {}                                  # each file opened once per run: the scene's window, the frames
    scene, text = load_input(scene_file, list(overrides), index=index, preset=preset, size=size, opened=opened)
    views = _chosen_views(scene, view)
    if print_scene:
        sys.stdout.write(text)
        sys.stdout.flush()
        if out is None:
            return
    plan = _Outputs.check(scene, output_stem(scene_file), out, len(views), as_json, force)
    renderer = Renderer(scene, views, slabs=slabs, scheduler=scheduler, opened=opened)
    per_view, rep = [], None
    with progress.bar(total=len(views), desc="views", unit="view") as bar, \
            contextlib.closing(renderer.render_views(bar=bar)) as results:
        for n, rgba, st, rep in results:
            per_view.append(_view_row(n if view is None else view, st))
            plan.add(n, rgba)
    plan.finish()
    if as_json or log.isEnabledFor(logging.DEBUG):   # the bytes needed take a pass over the selection: only
        held = renderer.held_bytes()                  # when printed
        report = _report(scene_file, renderer.method, plan.out, rep, per_view, held)
        if as_json:
            json.dump(report, sys.stdout, allow_nan=False)
            sys.stdout.write("\n")
        _log_report(report, rep, held)
    log.info(_summary(plan.out, scene, renderer, per_view, time.perf_counter() - t0))


def _error(message: str):
    from ..errors import IsplatError

    return IsplatError(message)


def _chosen_views(scene, view) -> tuple:
    """The scene's views, or only view ``view`` (``--view N``)."""
    from ..errors import IsplatError

    if view is None:
        return scene.views
    if not 0 <= view < len(scene.views):
        raise IsplatError(f"--view {view}: the scene has {len(scene.views)} view(s) (0..{len(scene.views) - 1})")
    return (scene.views[view],)


class _Outputs:
    """Where the frames go (a still per view, PNG on stdout, or a GIF or MP4 of all), checked before any frame
    is rendered: format, memory for the output buffers, files not overwritten without --force."""

    def __init__(self, scene, out, movie, paths, force):
        self.scene, self.out, self.movie, self.paths, self.force, self.frames = scene, out, movie, paths, force, []

    @classmethod
    def check(cls, scene, stem, out, n_views, as_json, force) -> "_Outputs":
        from ..errors import IsplatError
        from ..output import check_format, check_memory, check_outputs, frame_paths, output_buffer_bytes
        from ..threads import default_threads

        batch = n_views > 1
        if out is None:
            out = stem + (".gif" if batch else ".png")
        if as_json and out == "-":
            raise IsplatError("--json and -o - both want stdout; choose one")
        ext = check_format(out, batch)
        if out == "-" and sys.stdout.isatty():
            raise IsplatError("-o -: standard output is a terminal, not a place for PNG bytes; redirect it "
                              "(-o - > image.png) or pipe it (-o - | display -)")
        movie = ext in (".gif", ".mp4")
        itemsize = 8 if scene.render.precision == "float64" else 4
        im = scene.image
        check_memory(output_buffer_bytes(im.width, im.height, n_views, movie, ext, itemsize,
                                         scene.render.threads or default_threads(), scene.render.supersample),
                     f"{im.width}x{im.height}" + (f", {n_views} views" if movie else ""))
        paths = [] if out == "-" else ([Path(out)] if movie else frame_paths(out, n_views))
        check_outputs(paths, force)
        return cls(scene, out, movie, paths, force)

    def add(self, n: int, rgba) -> None:
        """Frame ``n``: written now (a still), or kept for the movie."""
        from ..output import write_still

        if self.movie:
            self.frames.append(rgba)
        else:
            write_still(self.out if self.out == "-" else str(self.paths[n]), rgba, self.scene.image.bit_depth,
                        self.force)

    def finish(self) -> None:
        if self.movie:
            from ..output import write_movie

            write_movie(self.out, self.frames, self.force, fps=self.scene.fps)


def _view_row(n: int, st) -> dict:
    """A view's entry in the report: its counters, the drawn one named for the technique's unit."""
    return {"view": n, "axis": ("+" if st.sign > 0 else "-") + st.axis, "voxels_examined": st.voxels_examined,
            "classification": st.classification,
            "voxels_splatted" if st.classification == "pre" else "samples": st.drawn,
            "slices": st.slices, "seconds": round(st.seconds, 6),
            **({"voxels_visited": st.voxels_tested} if st.classification in ("mip", "minip") else {})}


def _report(scene_file, method, out, rep, per_view, held) -> dict:
    """``--json``'s report; ``held``: the bytes the renderer holds for its frames (None when workers or one slab at
    a time hold them), as ``isplat stats --scene`` counts them (docs/stats.md)."""
    return {"scene": str(scene_file), "method": method, "output": out,
            "axes_loaded": rep.axes, "channels_loaded": rep.channels, "intervals": rep.intervals,
            "augmented_bytes_read": rep.augmented_bytes, "index_bytes_read": rep.index_bytes,
            "values_bytes_read": rep.values_bytes,
            "file_bytes_read": rep.file_bytes, "file_pages_read": rep.file_pages, "technique": rep.technique,
            "needed_voxels": rep.needed_voxels,
            "needed_axis": rep.needed_axis, "bytes_needed": rep.bytes_needed, "values_from": rep.values_from,
            "runs_file_bytes_read": rep.runs_file_bytes, "voxels_of_interest": rep.voxels_of_interest,
            "held_bytes": held, "held_bytes_per_voxel_of_interest":
                None if held is None else round(held / max(1, rep.voxels_of_interest), 4),
            "views": per_view}


def _log_report(report, rep, held) -> None:
    """The report on stderr with -v."""
    log.debug(f"read: {rep.augmented_bytes} bytes of augmented channels {rep.channels or '(none)'}; "
              f"{rep.index_bytes} bytes of index axes {rep.axes or '(none)'} for density intervals {rep.intervals}; "
              f"{rep.technique}: {rep.file_bytes} bytes read from the files (HDF5 chunks and metadata) for "
              f"{rep.bytes_needed} needed ({rep.needed_voxels} voxels"
              + (f" its quads read on axis {rep.needed_axis}" if rep.needed_axis else " of interest")
              + f" x {rep.channel_bytes_per_voxel} B + {rep.index_bytes_needed} B of index; read/needed "
              f"{rep.read_ratio:.2f}x"
              + (f"; in {rep.file_pages} bytes of 4 KB pages, {rep.page_ratio:.2f}x" if rep.file_pages >= 0 else "")
              + f"); channel values from {rep.values_from}"
              + (f" {rep.values_path} ({rep.values_bytes} bytes, {rep.values_file_bytes} read)"
                 if rep.values_file_bytes else "")
              + (f" {rep.values_path} ({rep.runs_file_bytes} bytes read)" if rep.runs_file_bytes else "")
              + (
                  f"; held {held} bytes, {held / max(1, rep.voxels_of_interest):.2f} per voxel of interest"
                  if held is not None else " (selections held by the workers or one slab at a time)"))
    for v in report["views"]:
        if "voxels_visited" in v:       # an intensity projection: the leave-out figure (isplat.splat.mip)
            share = v["voxels_visited"] / max(1, v["voxels_examined"])
            log.debug(f"view {v['view']}: axis {v['axis']}, {v['voxels_visited']} voxels visited of "
                      f"{v['voxels_examined']} voxels of interest ({share:.1%}; cells visited, summed over image "
                      f"bands), {v['samples']} samples taken ({v['classification']}), {v['seconds'] * 1000:.1f} ms")
            continue
        drawn = f"{v['voxels_splatted']} splatted" if "voxels_splatted" in v else f"{v['samples']} samples composited"
        log.debug(f"view {v['view']}: axis {v['axis']}, {v['voxels_examined']} voxels examined, {drawn} "
                  f"({v['classification']}-classified), {v['seconds'] * 1000:.1f} ms")


def _summary(out, scene, renderer, per_view, seconds: float) -> str:
    """The one line on stderr (not with -q): what was written, the technique, the method, how, how long."""
    techniques = sorted({v["classification"] for v in per_view}) or [scene.render.classification]
    label = "/".join(techniques) + ("" if set(techniques) & {"mip", "minip"} else "-classified")
    how = {"local": "", "streamed": f", {renderer.slabs} slabs front to back",
           "dask": f", on Dask ({renderer.scheduler}" + (f", {renderer.slabs} slabs" if renderer.slabs > 1 else "")
           + ")"}[renderer.mode]
    sheets = ", image-aligned sheets" if scene.render.sheets == "image" else ""
    n = len(per_view)
    return (f"isplat render: {'stdout' if out == '-' else out}: {n} view{'s' if n != 1 else ''}, "
            f"{label}{sheets}, {renderer.method} method{how}, {seconds:.2f} s")
