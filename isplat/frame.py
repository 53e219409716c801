"""One frame from a selection: views, per-frame tables, slabs of slices as partial images, and compositing.

No file I/O here: a frame is ``render_frame(selection, view)``, with the selection made once by
:mod:`isplat.selection`. The unit that threads, Dask workers and out-of-core streaming share is the slab: a
contiguous run of the frame's slices in front-to-back order, rendered by :func:`render_slab` into a
:class:`Partial` (premultiplied RGBA plus its saturation state). Slabs either continue one another (pass the
front slab's partial as ``state``: exactly the one-pass frame, early termination included) or are rendered
apart and composited in order with :func:`composite` ('over'; equal to the one-pass frame up to rounding
with early termination off, see docs/design.md for the bound with it on).

>>> import numpy as np
>>> from isplat.scene import parse_scene
>>> from isplat.selection import Selection
>>> vol = np.zeros((8, 8, 8), np.uint8); vol[2:6, 2:6, 2:6] = 200
>>> scene = parse_scene("[image]\\nwidth = 32\\nheight = 32\\n[transfer]\\nopacity = [[100, 0], [200, 0.8]]",
...                     ".", "example", data_required=False)
>>> sel = Selection.from_arrays(vol, scene)
>>> rgba, stats = render_frame(sel, views_for(scene, sel)[0])
>>> rgba.shape, stats.samples, stats.classification      # post-classified: samples composited
((32, 32, 4), 324, 'post')
"""

from __future__ import annotations

import itertools
import statistics
import time
from collections import namedtuple
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from . import camera as cam_mod
from . import grid, progress
from .errors import IsplatError
from .splat import traverse as T
from .splat.composite import TILE, finish, over, saturation
from .splat.shade import shade_table
from .threads import default_threads, run_parallel
from .transfer import alpha_table


@dataclass
class FrameStats:
    """What a frame visited and drew, each counter named for what it counts in the frame's technique
    (``classification``): pre-classified frames splat voxels (``voxels_splatted``), post-classified ones
    composite samples (``samples``); the other technique's counter is 0, and :attr:`drawn` is the frame's own."""

    axis: str
    sign: int
    voxels_examined: int
    voxels_splatted: int        # pre: voxels splatted (after cuts and early termination); post: 0
    slices: int
    seconds: float
    voxels_tested: int = 0      # voxels that reached the per-voxel stages (not skipped with their region,
                                # block or cell), summed over the image bands (a voxel near a band's edge
                                # is tested by both bands)
    classification: str = "pre" # the technique: "pre", "post", or "mip" / "minip" (render.mode)
    samples: int = 0            # post: samples composited (one per pixel and slice where a quad of interest is
                                # seen); mip/minip: samples taken; pre: 0
    # mip/minip: voxels_examined is the frame's voxels of interest, voxels_tested those in units visited (not
    # skipped), summed over the image bands (a unit reaching two bands counts in each)

    @property
    def drawn(self) -> int:
        """What the technique drew: voxels splatted (pre) or samples composited (post) or taken (mip/minip)."""
        return self.voxels_splatted if self.classification == "pre" else self.samples

    @property
    def drawn_unit(self) -> str:
        """What :attr:`drawn` counts, in words: "voxels splatted", "samples composited" or "samples taken"."""
        return {"pre": "voxels splatted", "post": "samples composited"}.get(self.classification, "samples taken")


@dataclass(frozen=True)
class View:
    """Everything of one frame but the selection: where the camera is and the scene's per-frame settings."""

    frame: cam_mod.ViewFrame
    geom: cam_mod.VolumeGeometry
    render: object              # scene.RenderOptions
    shading: object             # scene.Shading
    cuts: tuple
    background: tuple

    @cached_property
    def axis_sign(self) -> tuple[str, int]:
        """The principal (slice) axis and its traversal sign."""
        return cam_mod.principal_axis(self.frame, self.geom)

    @cached_property
    def order(self) -> np.ndarray:
        """The slice indices of the principal axis, front to back."""
        return cam_mod.slice_order(self.frame, self.geom, *self.axis_sign)


def scene_geometry(scene, shape, spacing_ijk, source: str = "volume", axes_lps=None) -> cam_mod.VolumeGeometry:
    """Where the volume sits: the scene's ``[volume]`` (spacing defaults to the data's, from ``source``; axes to
    the data's orientation ``axes_lps``, world = patient space, or the identity without one)."""
    from .scene import spacing_problem

    sp = scene.volume.spacing or spacing_ijk
    problem = spacing_problem(sp)
    if problem:          # the scene's own spacing is checked when it is read; this is the data's
        raise IsplatError(f"{source}: attribute 'spacing_ijk' is {list(sp)}: {problem} "
                          "(or set volume.spacing in the scene)")
    axes = scene.volume.axes if scene.volume.axes is not None else axes_lps
    return cam_mod.volume_geometry(shape, sp, scene.volume.origin, axes)


def views_for(scene, data, cameras=None) -> list[View]:
    """The :class:`View` of each camera (default: the scene's views) for ``data`` (anything with ``shape``
    and ``spacing_ijk``: a Selection or an augmented file, whose ``axes_lps``, if any, places the volume and
    gives named views their meaning)."""
    axes_lps = getattr(data, "axes_lps", None)
    geom = scene_geometry(scene, data.shape, data.spacing_ijk, str(getattr(data, "path", "volume")), axes_lps)
    n = scene.render.supersample                # frames at n times the image's size (finish_image box-filters)
    W, H = scene.image.width * n, scene.image.height * n
    return [View(cam_mod.view_frame(c, geom, W, H, axes_lps), geom, scene.render, scene.shading, scene.cuts,
                 tuple(scene.image.background)) for c in (scene.views if cameras is None else cameras)]


def axes_of(views) -> str:
    """The principal axes of ``views``, in i, j, k order: the index axes their frames read."""
    used = {v.axis_sign[0] for v in views}
    return "".join(a for a in grid.AXES if a in used)


@dataclass
class Partial:
    """A slab's partial image: premultiplied RGBA, its saturation state (``sat`` per pixel, ``tile_sat`` per
    tile), and per thread band the counters (voxels examined, splatted, slices)."""

    img: np.ndarray
    sat: np.ndarray
    tile_sat: np.ndarray
    band_stats: np.ndarray       # int64[bands, 4], see traverse.Buffers


@dataclass
class Setup:
    """A frame's tables and scratch buffers, made once per frame (:func:`prepare`); renders one slab at a time.
    ``plan`` is the technique's per-frame plan (a named tuple, :mod:`isplat.splat.traverse`), ``lists`` each
    thread's own scratch for it; None and [] for an empty selection."""

    view: View
    plan: tuple | None
    lists: list                 # per thread, the technique's scratch (its touched-pixel and visible-cell lists)
    rows: np.ndarray            # int64[bands, 2]: each image band's rows [y0, y1)
    mine: list                  # per thread, the bands it would render at equal speed (queue[t::threads])
    tile_npix: np.ndarray
    dtype: type                 # the image's float type (render.precision)
    et: float
    threads: int
    empty: bool
    order: np.ndarray | None = None    # the frame's sheets front to back, when not the view's slices
    band_seconds: np.ndarray | None = None  # float64[bands]: each band's CPU time so far (render_slab)
    queue: np.ndarray | None = None     # int64[bands]: the bands in the order the threads take them (band_queue)

    def __post_init__(self):
        if self.band_seconds is None:
            self.band_seconds = np.zeros(len(self.rows))
        if self.queue is None:
            self.queue = np.arange(len(self.rows), dtype=np.int64)

    @property
    def sheets(self) -> np.ndarray:
        """What render_slab's ``start:stop`` count: the principal axis's slices (``view.order``), or the
        depth slabs of image-aligned sheets (``render.sheets = "image"``, :mod:`isplat.splat.sheets`)."""
        return self.view.order if self.order is None else self.order


@dataclass(frozen=True)
class FrameTables:
    """What :func:`prepare` works out for every technique, from which a technique makes its plan: the view's
    principal ``axis`` and its projection (``proj``, :func:`isplat.camera.projection`), the unit distance, the
    cutting planes' rows in slice coordinates (``cuts``), the axis-aligned slices' geometry (``geo``,
    :data:`isplat.splat.traverse.SliceGeometry`) and opacities (``atab``, corrected for the slices' path
    length), the shading table, the bands' rows, the most pixels of a band (``band_px``) and the number of
    threads' scratch to make (``threads``)."""

    sel: object
    view: View
    dtype: type
    threads: int
    rows: np.ndarray
    band_px: int
    axis: str
    proj: object
    unit: float
    cuts: np.ndarray
    geo: tuple
    atab: np.ndarray
    shade: np.ndarray


# The techniques, by the name :func:`technique_of` gives a frame's settings: each a module with ``plan(tables)``
# returning its plan (registered with :func:`isplat.splat.traverse.register`), its threads' scratch and its
# order of sheets (None: the view's slices). Adding a technique is adding a module and its line here. (Names
# relative to isplat: isplat imports itself only relatively, scripts/ab.py loads copies of it side by side.)
TECHNIQUES = {"pre": ".splat.pre", "post": ".splat.post", "image-sheets": ".splat.sheets", "mip": ".splat.mip",
              "minip": ".splat.mip"}


def technique_of(ro) -> str:
    """The technique of a frame's settings (``render``): an intensity projection (``render.mode``), image-aligned
    sheets, or the classification's."""
    if ro.mode != "composite":
        return ro.mode
    return "image-sheets" if ro.sheets == "image" else ro.classification


def prepare(sel, view: View, et: float | None = None, bands: "BandLearning | None" = None) -> Setup:
    """Make the frame's tables: the bands (by what ``bands`` learned), what every technique shares
    (:class:`FrameTables`: opacity corrected for this view's path length, shading for its lights, the §3
    coefficients), and the technique's plan."""
    import importlib

    ro, frame = view.render, view.frame
    dtype = np.float64 if ro.precision == "float64" else np.float32
    threads = ro.threads or default_threads()
    et_val = float(ro.early_termination if et is None else et)
    rows = band_rows(bands, view, threads)
    queue = band_queue(bands, view, threads, len(rows))
    mine = [queue[t::threads] for t in range(min(threads, len(rows)))]
    tile_npix = _tile_pixels(frame.height, frame.width)
    if sel.empty:
        return Setup(view, None, [], rows, mine, tile_npix, dtype, et_val, threads, True, queue=queue)
    tables = frame_tables(sel, view, dtype, threads, rows, len(mine))
    plan, lists, order = importlib.import_module(TECHNIQUES[technique_of(ro)], __package__).plan(tables)
    return Setup(view, plan, lists, rows, mine, tile_npix, dtype, et_val, threads, False, order, queue=queue)


def frame_tables(sel, view: View, dtype, threads: int, rows: np.ndarray, n_lists: int) -> FrameTables:
    """:class:`FrameTables` of a frame (``threads`` its threads, ``n_lists`` how many of them render)."""
    ro, geom, frame = view.render, view.geom, view.frame
    axis = view.axis_sign[0]
    proj = cam_mod.projection(frame, geom, axis)
    unit = sel.unit_distance or float(geom.spacing.min())
    n = ro.slice_stride             # every n-th slice sampled (post): each for the path of n slices
    ic = grid.SLICE_AXES[axis][2]
    coef, steps = _floats(proj.coef), tuple(_floats(row) for row in proj.steps)
    cuts = cut_coefficients(view.cuts, geom, axis)
    if frame.projection == "perspective":
        atab = alpha_table(sel.luts, None)
        geo = T.SliceGeometry(coef, steps, _floats(geom.q - frame.e), True, n * float(geom.spacing[ic]) / unit,
                              float((geom.q - frame.e) @ geom.unit_axes[ic]), float(geom.spacing[ic]), cuts,
                              eye_terms(frame, geom, ic, ro.footprint_radius, n))
    else:
        atab = alpha_table(sel.luts, n * proj.ds / unit)
        geo = T.SliceGeometry(coef, steps, (0.0, 0.0, 0.0), False, 1.0, 0.0, 1.0, cuts, (0.0,) * 9)
    shade = (shade_table(view.shading, frame, geom, threads=threads) if sel.use_shade
             else np.zeros((1, 6), np.float32))
    band_px = int((rows[:, 1] - rows[:, 0]).max()) * frame.width
    return FrameTables(sel, view, dtype, n_lists, rows, band_px, axis, proj, unit, cuts, geo, atab, shade)


# A voxel whose footprint's sigma subtends more than this angle (radians) from the eye gets its opacity per
# pixel, along each pixel's own ray (pre._splat_rays), rather than along its own ray: with the voxel's own
# ray, the opacity of a pixel in a uniform region is off by about half the square of that angle times
# (sec^2 + tan^2) of the ray's angle to the slice normal (3e-4 to 1e-3 at this angle; up to 30% for the voxels
# one spacing from an eye inside the volume).
WIDE_ANGLE = 1.0 / 40.0


def eye_terms(frame, geom, ic: int, radius: float, stride: int = 1) -> tuple:
    """The per-frame terms of traverse.SliceGeometry.eye (layout traverse.EY_*) for slices along grid axis ``ic``
    and a footprint cut off at ``radius`` sigmas; ``stride``: every n-th slice sampled (render.slice_stride),
    each slab that many slices thick."""
    ds = float(geom.spacing[ic])
    n_c = int(geom.n_ijk[ic])
    ce = float(geom.to_grid(frame.e)[ic])
    h0 = max(-0.5 - ce, ce - (n_c - 0.5), 0.0) * ds             # eye to the box, along the slice normal
    diag = float(np.linalg.norm(geom.n_ijk * geom.spacing))
    f = float((frame.e - frame.p) @ frame.w) / frame.pixel_size  # focal length in pixels
    n = geom.unit_axes[ic]
    slab = stride * ds
    return (slab, h0, float(frame.clip), min(1.0, slab / diag), WIDE_ANGLE * f * radius, float(frame.u @ n),
            -float(frame.v @ n), -float(frame.w @ n) * f, f * f)


def blank(setup: Setup, zero: bool = True) -> Partial:
    """An empty partial image (nothing in front): the state a frame starts from (``zero`` False: the image and
    its saturation not zeroed yet; render_slab's threads zero their own rows)."""
    H, W = setup.view.frame.height, setup.view.frame.width
    make = np.zeros if zero else np.empty
    return Partial(make((H, W, 4), setup.dtype), make((H, W), np.uint8),
                   np.zeros(setup.tile_npix.shape, np.int32), np.zeros((len(setup.rows), 4), np.int64))


def render_slab(setup: Setup, start: int = 0, stop: int | None = None, state: Partial | None = None,
                finished: np.ndarray | None = None, meanwhile=None) -> Partial:
    """Render the slices ``order[start:stop]`` of the frame (front to back) over ``state`` (the partial image
    of the slices in front, updated in place; a blank one when None) and return it.

    ``finished`` (an image like the partial's; only for the frame's last slices, without supersampling): each
    thread then also finishes its bands' rows into it over the view's background (:func:`finish_image`'s
    pixels) as soon as its slices are done, with no second round of the threads; with nothing to render, the
    partial is finished as it is. A blank partial's rows are zeroed by the threads that render them.
    ``meanwhile()``, if given, runs in this thread while the frame's threads render (:func:`run_parallel`)."""
    slices = setup.sheets[start:stop]
    if setup.empty or slices.size == 0:
        if meanwhile is not None:
            meanwhile()
        part = blank(setup) if state is None else state
        if finished is not None:
            finished[...] = finish_image(part.img, setup.view.background, 1, setup.threads)
        return part
    part = blank(setup, zero=False) if state is None else state
    et = part.img.dtype.type(setup.et)
    bg = np.asarray(setup.view.background, dtype=np.float64)

    queue = itertools.count()   # setup.queue's bands in turn, each taken by the first thread free (next() is atomic)
    n_bands = len(setup.rows)
    each = np.arange(n_bands, dtype=np.int64)

    def run(t):
        buf = T.Buffers(part.img, part.sat, part.tile_sat, setup.tile_npix, part.band_stats)
        ok = True
        while (qi := next(queue)) < n_bands:     # band by band, each timed (band_rows balances by the times)
            bi = int(setup.queue[qi])
            c0 = time.thread_time()
            y0, y1 = setup.rows[bi]
            if state is None:
                part.img[y0:y1] = 0
                part.sat[y0:y1] = 0
            T.render(slices, start, setup.plan, setup.lists[t], buf, T.Bands(setup.rows, each[bi:bi + 1], et))
            if finished is not None:
                ok = finish(part.img[y0:y1], bg, finished[y0:y1]) and ok
            setup.band_seconds[bi] += time.thread_time() - c0
        return ok

    if not all(run_parallel(run, range(len(setup.mine)), setup.threads, meanwhile)):
        raise IsplatError(NON_FINITE)
    return part


def composite(front: Partial, back: Partial, et: float = 1.0) -> Partial:
    """``front`` over ``back`` (premultiplied, in visibility order) as a new partial; counters add up, and the
    saturation state is that of the result for early-termination opacity ``et``."""
    out = Partial(np.empty_like(front.img), np.empty_like(front.sat), np.empty_like(front.tile_sat),
                  front.band_stats + back.band_stats)
    over(front.img, back.img, out.img)
    saturation(out.img, out.img.dtype.type(et), out.sat, out.tile_sat)
    return out


def slab_bounds(n_slices: int, n_slabs: int) -> list[tuple[int, int]]:
    """Cut ``n_slices`` slices (in front-to-back order) into ``n_slabs`` contiguous slabs ``[start, stop)``."""
    edges = np.linspace(0, n_slices, max(1, n_slabs) + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def frame_stats(view: View, part: Partial, seconds: float) -> FrameStats:
    """The frame's counters: the voxels examined are those of the slices of the band that went deepest (each
    band goes front to back until its pixels saturate), one band counts each splatted voxel (pre) or
    composited sample (post), and the slices are those of the deepest band."""
    axis, sign = view.axis_sign
    bs = part.band_stats
    technique = view.render.classification if view.render.mode == "composite" else view.render.mode
    pre = technique == "pre"
    drawn = int(bs[:, 2].sum())
    return FrameStats(axis, sign, int(bs[:, 0].max()), drawn if pre else 0, int(bs[:, 3].max()), seconds,
                      int(bs[:, 1].sum()), technique, 0 if pre else drawn)


def render_frame(sel, view: View, et: float | None = None, bands: "BandLearning | None" = None):
    """Render one frame; returns (straight RGBA float array (H, W, 4) over the background, FrameStats).
    ``bands``: what the frames before this one learned of their image bands, and where this one's times go
    (:class:`BandLearning`; the caller keeps it from frame to frame; None: even bands, nothing kept).

    With a progress bar (stderr a terminal) the slices go in slabs that continue one another, so the bar can
    move; the image and the counters are the same as in one pass.
    """
    t0 = time.perf_counter()
    bands = BandLearning() if bands is None else bands
    setup = prepare(sel, view, et, bands)
    n = len(setup.sheets)
    slabs = slab_bounds(n, 20) if progress.enabled() and n >= 40 and not setup.empty else [(0, n)]
    part = None
    # without supersampling the last slices' threads finish their own rows (render_slab's ``finished``)
    H, W = view.frame.height, view.frame.width
    out = np.empty((H, W, 4), setup.dtype) if view.render.supersample == 1 else None
    for i, (start, stop) in enumerate(progress.bar(slabs, desc=f"slices ({n})", unit="slab",
                                                   disable=len(slabs) == 1)):
        # what the frames before this one found of their bands is learned while this one's threads render
        part = render_slab(setup, start, stop, part, out if i == len(slabs) - 1 else None,
                           meanwhile=(lambda: learn_pending(bands)) if i == 0 else None)
    bands.pending.append(BandTimes(setup.rows, setup.band_seconds, view, setup.threads, setup.empty, setup.queue))
    if out is None:
        out = finish_image(part.img, view.background, view.render.supersample, setup.threads)
    return out, frame_stats(view, part, time.perf_counter() - t0)


def finish_image(img: np.ndarray, background, supersample: int = 1, threads: int = 1) -> np.ndarray:
    """Premultiplied RGBA over the background colour -> straight RGBA (float); with ``supersample`` n > 1 the
    frame (n times the image's width and height) is first box-filtered down, each pixel the mean of its n x n
    (premultiplied, so colour is weighted by opacity; the background goes over after, which is the same).
    ``threads`` threads take a block of rows each (the same pixels, computed alike)."""
    if supersample > 1:
        img = box_filter(img, supersample)
    out = np.empty(img.shape, dtype=img.dtype)
    bg = np.asarray(background, dtype=np.float64)
    edges = np.linspace(0, img.shape[0], max(1, min(threads, img.shape[0])) + 1).round().astype(int)
    ok = run_parallel(lambda r: finish(img[r[0]:r[1]], bg, out[r[0]:r[1]]), zip(edges[:-1], edges[1:]), threads)
    if not all(ok):
        raise IsplatError(NON_FINITE)
    return out


NON_FINITE = "render produced non-finite pixels; please report this scene"


def box_filter(img: np.ndarray, n: int) -> np.ndarray:
    """The mean of every n x n block of pixels of ``img`` (H*n, W*n, C) -> (H, W, C), summed in float64."""
    h, w = img.shape[0] // n, img.shape[1] // n
    if (h * n, w * n) != img.shape[:2]:
        raise IsplatError(f"supersample {n}: the frame is {img.shape[1]}x{img.shape[0]}, not a multiple of {n}")
    return img.reshape(h, n, w, n, -1).mean(axis=(1, 3), dtype=np.float64).astype(img.dtype)


def cut_coefficients(cuts, geom, axis, dtype=np.float64) -> np.ndarray:
    """Cutting planes as rows (g0, ga, gb, gc) in slice coordinates: keep ``g0 + a ga + b gb + c gc >= 0``."""
    ia, ib, ic = grid.SLICE_AXES[axis]
    S = geom.steps
    rows = []
    for cut in cuts:
        n = np.asarray(cut.normal, float)
        rows.append([(geom.q - np.asarray(cut.point, float)) @ n, S[ia] @ n, S[ib] @ n, S[ic] @ n])
    return np.asarray(rows, dtype=dtype).reshape(-1, 4)


BANDS_PER_THREAD = 2    # even image bands per thread (see image_bands)
LEARNED_PER_THREAD = 2  # learned bands per thread (_next_bands, band_layout): 1 repeats less work on a quiet
                        # machine, 2 lets a free thread take over from one slowed by another process
MIN_BAND_TILES = 4


def _floats(values) -> tuple:
    return tuple(float(x) for x in values)


@lru_cache(maxsize=8)
def _tile_pixels(h: int, w: int, tile: int = TILE) -> np.ndarray:
    """Pixels in each tile of an h x w image (edge tiles are smaller)."""
    rows = np.minimum(tile, h - np.arange(0, h, tile))
    cols = np.minimum(tile, w - np.arange(0, w, tile))
    out = np.outer(rows, cols).astype(np.int32)
    out.flags.writeable = False
    return out


def image_bands(height: int, threads: int, tile: int = TILE) -> np.ndarray:
    """The image's bands of rows cut evenly, ``int64[bands, 2]`` of ``[y0, y1)``: whole tiles, all of one height
    but the last, BANDS_PER_THREAD per thread (one for one thread), at least MIN_BAND_TILES tiles high. Each
    band walks the slices on its own and tests only the regions that reach it
    (:func:`isplat.splat.traverse.bin_regions`); a voxel whose footprint crosses a band's edge is tested by both
    bands, so more bands repeat more work; each thread takes the next band when it is free (render_slab), at
    equal speed every n-th band, so that the middle of the image, where the work is, is shared. A frame's bands
    are these, or as many cut by the work the frames before it
    found (:func:`band_rows`). The image depends neither on the bands nor on which thread renders which."""
    return _even_bands(height, threads, tile, BANDS_PER_THREAD, MIN_BAND_TILES)


@lru_cache(maxsize=32)
def _even_bands(height: int, threads: int, tile: int, per_thread: int, least: int) -> np.ndarray:
    """:func:`image_bands` (read-only, made once per image height, threads and settings: a frame's first of its
    kind, and every frame of one thread, takes them)."""
    n_tiles = -(-height // tile)
    per = max(least, -(-n_tiles // (1 if threads <= 1 else threads * per_thread)))
    y0 = np.arange(0, n_tiles, per) * tile
    return read_only(np.stack([y0, np.minimum(y0 + per * tile, height)], axis=1))


def band_rows(bands: "BandLearning | None", view: View, threads: int) -> np.ndarray:
    """The frame's bands: :func:`image_bands` for the first frame of its kind (principal axis and direction,
    image size, threads, classification, sheets) in ``bands`` (or with None), then what the frames before it
    learned (:func:`learn_bands`). A free thread takes the next band; the image does not depend on the bands."""
    learned = None if bands is None else bands.costs.get(_balance_key(view, threads))
    return image_bands(view.frame.height, threads) if learned is None else learned.rows


def band_queue(bands: "BandLearning | None", view: View, threads: int, n_bands: int) -> np.ndarray:
    """The order in which the threads take the frame's ``n_bands`` bands (:func:`band_rows`'s), ``int64[bands]``:
    the image's order for even bands, :func:`band_layout`'s for learned ones (the large bands first)."""
    learned = None if bands is None else bands.costs.get(_balance_key(view, threads))
    if learned is None or learned.queue is None or len(learned.queue) != n_bands:
        return np.arange(n_bands, dtype=np.int64)
    return learned.queue


def _balance_key(view: View, threads: int) -> tuple:
    ro = view.render
    return view.axis_sign, view.frame.height, view.frame.width, threads, ro.classification, ro.sheets, ro.mode


@dataclass
class Learned:
    """What the frames of one kind learned of their bands (:func:`learn_bands`): the work per tile row, the
    next frame's bands and the order the threads take them in (None: the image's), and for the last few bands
    used (by their first rows and their order) the busiest thread's work over the mean (measured: the median of
    their last frames, ``recent``)."""

    est: np.ndarray | None      # None after the first frame
    rows: np.ndarray
    tried: dict
    queue: np.ndarray | None = None
    recent: tuple = ()          # the busiest thread's work over the mean in the last RECENT frames on these bands

    def __post_init__(self):
        # read-only, as image_bands' rows: the kernels take them (bin_regions, traverse.render's Bands), and
        # numba types a read-only array apart from a writable one, so writable learned rows compiled those
        # kernels a second time (seconds, in the fourth frame of a run; not among the prebuilt kernels)
        self.rows = read_only(self.rows)


def read_only(a: np.ndarray) -> np.ndarray:
    """``a`` as a read-only C-contiguous int64 array (itself when it is one already, else a copy)."""
    a = np.ascontiguousarray(a, dtype=np.int64)
    if a.flags.writeable:
        a = a.copy()
        a.flags.writeable = False
    return a


BALANCE_SLACK = 0.03    # bands are kept while the busiest thread's work is at most this much above the mean
TRIED = 4               # bands remembered with what they gave
RECENT = 3              # frames whose median decides (one frame slowed by other work moves nothing)


BandTimes = namedtuple("BandTimes", "rows band_seconds view threads empty queue")
BandTimes.__doc__ = """What :func:`learn_bands` takes of a frame's :class:`Setup` (and keeps, unlike the set-up's
buffers, until the next frame learns from it)."""


@dataclass
class BandLearning:
    """What a run of frames learned of their image bands: per kind of frame (:func:`_balance_key`) what
    :func:`learn_bands` found (``costs``), and the frames still to be learned from (``pending``, their
    :data:`BandTimes`; :func:`learn_pending`). The state of a renderer's frames, owned by whoever renders a
    run of frames (:class:`isplat.renderer.Renderer`, beside a cached selection in :func:`isplat.render` and on
    a Dask worker), not by the selection, which stays unchanged and can be shared."""

    costs: dict = field(default_factory=dict)
    pending: list = field(default_factory=list)


def learn_pending(bands: BandLearning) -> None:
    """Learn from the frames rendered since the last call (``bands.pending``, :func:`learn_bands`), oldest
    first. :func:`render_frame` calls it while the next frame's threads render, so that the learning (Python,
    a few tenths of a millisecond) is not a serial part of any frame; the bands then follow the frames before
    the last one."""
    while True:
        try:
            times = bands.pending.pop(0)            # one caller learns each frame, also from two threads
        except IndexError:
            return
        learn_bands(bands.costs, times)


def learn_bands(costs: dict, setup: Setup) -> None:
    """Learn from the frame (``setup``: its bands' rows and times, view and threads) where the next frames'
    bands go (``costs``: :attr:`BandLearning.costs`). The first frame of a kind only marks it seen: its times
    hold one-time costs (fresh memory, cold caches) that bands cut by them would follow. The second starts the
    profile of the work per tile row (:func:`_profile`), and the bands move (:func:`_next_bands`) only on a
    profile of two frames or more, so that one frame's noise does not move them. After that the bands are
    learned from only when the last RECENT frames on them (at least two: the lower of two, the median of three)
    had their busiest thread more than BALANCE_SLACK above the mean: a frame with a band slowed by other work on
    the machine (on a shared host a band's CPU time grows too) moves nothing. (Moved by one such frame, bands could
    stay worse than those before, within :func:`_next_bands`' tolerance.) That measure is also what the bands
    tried are remembered with."""
    if len(setup.rows) < 2 or setup.empty:
        return
    key, threads = _balance_key(setup.view, setup.threads), setup.threads
    old = costs.get(key)
    if old is None:
        costs[key] = Learned(None, setup.rows, {})
        return
    queue = setup.queue
    measured = _thread_sums(setup.band_seconds, threads, queue)
    recent = (old.recent + (float(measured.max() / measured.mean()),))[-RECENT:]
    if old.est is not None and (len(recent) < 2 or statistics.median_low(recent) <= 1.0 + BALANCE_SLACK):
        old.recent = recent
        return
    est = _profile(old.est, setup.rows, setup.band_seconds, setup.view.frame.height)
    costs[key] = Learned(est, setup.rows, {}, queue, recent) if old.est is None else \
        _next_bands(est, setup.rows, queue, old.tried, threads, setup.view.frame.height, recent)


def _thread_sums(per_band, threads: int, queue) -> np.ndarray:
    """Each thread's share of ``per_band`` at equal speed, as :func:`render_slab`'s threads take the bands: in
    the order ``queue``, each by the thread free first (the first ``threads`` bands one each; then the thread
    whose bands so far cost least, the lowest on a tie)."""
    return np.array(_list_schedule(list(per_band), threads, list(queue)))


def _list_schedule(per_band: list, threads: int, queue: list) -> list:
    """:func:`_thread_sums` on plain lists (balanced_bands calls it for every cut it tries)."""
    per = [0.0] * threads
    for b in queue:
        t = per.index(min(per))
        per[t] += per_band[b]
    return per


def _profile(est: np.ndarray | None, rows: np.ndarray, seconds: np.ndarray, height: int) -> np.ndarray:
    """The work per tile row after a frame on bands ``rows`` that took ``seconds``: each band's time spread over
    its rows in the proportions of ``est`` (evenly at first; a tenth of the band's mean is added to every row,
    so that a row once found idle can be found busy), so that bands cut at other rows refine the profile, and
    averaged with ``est``, so that one frame's noise counts for half."""
    known = np.zeros(-(-height // TILE)) if est is None else est
    lo, hi = rows[:, 0] // TILE, -(-rows[:, 1] // TILE)
    band = np.repeat(np.arange(len(lo)), hi - lo)              # tile row -> its band
    shape = known + (0.1 * np.add.reduceat(known, lo) / (hi - lo) + 1e-12)[band]
    new = (seconds / np.add.reduceat(shape, lo))[band] * shape
    return new if est is None else 0.5 * (new + est)


def _next_bands(est: np.ndarray, rows: np.ndarray, queue: np.ndarray, tried: dict, threads: int,
                height: int, recent: tuple = ()) -> Learned:
    """The bands after ``rows`` (taken in the order ``queue``): kept while the busiest thread's work (by the profile
    ``est``) is at most BALANCE_SLACK or half a tile row's work (as close as bands of whole tiles may come) above
    the mean; else LEARNED_PER_THREAD bands per thread cut where the profile says the work is equal
    (:func:`balanced_bands`; fewer cuts through the busy rows than even bands make, each repeating work) when that
    is predicted better than the best of the last TRIED bands tried, by more than the slack, or else the best of
    those again (a cut that cannot be balanced at whole tiles does not swing between two)."""
    cum = np.concatenate([[0.0], np.cumsum(est)])

    def per_thread(r, q):
        return _thread_sums(cum[-(-r[:, 1] // TILE)] - cum[r[:, 0] // TILE], threads, q)

    now = per_thread(rows, queue)
    busiest, mean = float(now.max()), float(now.mean())
    tried = dict(tried)
    tried.pop(key := (tuple(rows[:, 0].tolist()), tuple(queue.tolist())), None)
    tried[key] = statistics.median_low(recent) if recent else busiest / mean
    while len(tried) > TRIED:
        del tried[next(iter(tried))]
    if busiest > mean + max(BALANCE_SLACK * mean, 0.5 * float(est.max())):
        n_bands = min(LEARNED_PER_THREAD * threads, len(est))
        cut, order = balanced_bands(est, n_bands, threads, height), band_layout(n_bands, threads)[1]
        if (tuple(cut[:, 0].tolist()), tuple(order.tolist())) not in tried and \
                per_thread(cut, order).max() < (min(tried.values()) - BALANCE_SLACK) * mean:
            return Learned(est, cut, tried, order)
        best = min(tried, key=tried.get)
        if best != key:
            starts, order = (np.array(x, np.int64) for x in best)
            return Learned(est, np.stack([starts, np.append(starts[1:], height)], axis=1), tried, order)
    return Learned(est, rows, tried, queue, recent)


def band_layout(n_bands: int, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """Learned bands: where ``n_bands`` bands for ``threads`` threads end in the image's order, as shares of the
    frame's work, and the order in which the threads take them (``int64[bands]`` of band indices). With two
    bands per thread each thread's first band is twice its second (the n large bands 2/3 of the work, the n
    small ones 1/3), so that threads taking the next band when free (:func:`render_slab`) even out a thread
    slowed by another process: at equal speed thread t takes the t-th large band and the t-th small one (half
    the work each); with one thread at half speed it does one large band while the other does the rest, and
    both end at 2/3 of the one-speed time, as the two threads' summed speed allows. The large bands are the
    middle of the image and are taken first; the small ones are its top and bottom (half of them each), taken
    after, so that two of the cuts fall where the work thins out: a cut repeats the work of the cells that
    cross it, which is least where there is least work (docs/worksplit.md counts it). Otherwise equal shares
    in the image's order.

    >>> ends, order = band_layout(4, 2)
    >>> ends.round(4).tolist(), order.tolist()
    ([0.1667, 0.5, 0.8333, 1.0], [1, 2, 0, 3])
    >>> band_layout(3, 2)[0].round(4).tolist(), band_layout(3, 2)[1].tolist()
    ([0.3333, 0.6667, 1.0], [0, 1, 2])
    """
    if threads < 2 or n_bands != 2 * threads:
        return np.arange(1, n_bands + 1) / n_bands, np.arange(n_bands, dtype=np.int64)
    top = threads // 2
    per = np.r_[np.ones(top), np.full(threads, 2.0), np.ones(threads - top)]
    order = np.r_[np.arange(top, top + threads), np.arange(top), np.arange(top + threads, n_bands)]
    return np.cumsum(per) / per.sum(), order.astype(np.int64)


def balanced_bands(est: np.ndarray, n_bands: int, threads: int, height: int, tile: int = TILE) -> np.ndarray:
    """``n_bands`` bands of whole tiles of an image ``height`` rows high (``int64[bands, 2]`` of ``[y0, y1)``)
    for a cost ``est`` per tile row, the threads taking the bands in :func:`band_layout`'s order, each by the
    thread free first (:func:`_thread_sums`, at equal speed): cut where the cumulated cost reaches the layout's
    shares of the whole, then cuts moved a tile at a time while that lowers the busiest thread's cost (or, as
    much, the sum of squares of the threads' costs). In plain Python: a few bands, and numpy's calls cost more
    than the sums."""
    n_tiles = len(est)
    cum = np.concatenate([[0.0], np.cumsum(est)])
    ends, order = band_layout(n_bands, threads)
    order = order.tolist()
    q = np.rint(np.interp(cum[-1] * ends[:-1], cum, np.arange(n_tiles + 1)))
    edges = [0, *np.clip(q, 1, n_tiles - 1).astype(int).tolist(), n_tiles]
    for i in range(1, n_bands):                       # every band at least one tile, from the top ...
        edges[i] = max(edges[i], edges[i - 1] + 1)
    for i in range(n_bands - 1, 0, -1):               # ... and from the bottom
        edges[i] = min(edges[i], edges[i + 1] - 1)
    cum = cum.tolist()

    def score(e):
        per = _list_schedule([cum[e[b + 1]] - cum[e[b]] for b in range(n_bands)], threads, order)
        return max(per), sum(p * p for p in per)

    best = score(edges)
    for _ in range(2 * n_tiles):
        moved = False
        for i in range(1, n_bands):
            for d in (-1, 1):
                if edges[i - 1] < edges[i] + d < edges[i + 1]:
                    edges[i] += d
                    s = score(edges)
                    if s < best:
                        best, moved = s, True
                    else:
                        edges[i] -= d
        if not moved:
            break
    rows = np.array(edges, np.int64) * tile
    rows[-1] = height
    return np.stack([rows[:-1], rows[1:]], axis=1)
