"""Render a scene: load only what it needs, then splat each view (paper §2.2, §3).

>>> r = Renderer(load_scene("head.toml"))          # doctest: +SKIP
>>> rgba = r.render_view(r.scene.views[0])           # float (H, W, 4), straight alpha over the background

What a scene needs, and nothing more, is read: the index axes its views use, only the blocks in the transfer
function's non-zero-opacity intervals, the ``normal`` channel only when shading is on, the
``gradient_magnitude`` channel only when the transfer function modulates opacity by it, and the ``density``
channel only for the ``full`` method (the index already carries densities).
"""

from __future__ import annotations

import functools
import os
import time
from dataclasses import dataclass, field

import numpy as np

from . import camera as cam_mod
from . import progress
from .augfile import open_augmented
from .errors import IsplatError
from .splat.footprint import make_footprint
from .transfer import alpha_table, build_luts

_EMPTY_U8 = np.zeros(1, dtype=np.uint8)
_EMPTY_U16 = np.zeros(1, dtype=np.uint16)


@dataclass
class FrameStats:
    axis: str
    sign: int
    voxels_examined: int
    voxels_splatted: int
    slices: int
    seconds: float


@dataclass
class LoadReport:
    augmented_bytes: int = 0          # bytes read from the augmented file's channels
    index_bytes: int = 0              # bytes read from the index file
    index_decoded_bytes: int = 0      # the decoded blocks (LoadedAxis arrays), before selection
    channels: list = field(default_factory=list)
    axes: list = field(default_factory=list)
    intervals: list = field(default_factory=list)


def shade_table(shading, frame, geom, dtype=np.float32, threads: int = 1) -> np.ndarray:
    """Per normal code: (diffuse r, g, b, specular r, g, b) for this view's lights (Phong, infinite viewer),
    or just (diffuse, specular) when every light is white.

    Lights are given in camera space; normals are in the volume's i, j, k axes, so the lights are turned
    into volume axes once per frame and the 65,536 codes are shaded in one compiled pass.
    """
    from .normals import decode_lut
    from .splat.kernels import shade_codes

    R = np.stack([frame.u, frame.v, frame.w])          # camera -> world: x*u + y*v + z*w
    view = geom.unit_axes @ frame.w                    # towards the viewer, volume axes
    rows = []
    for light in shading.lights:
        lw = np.asarray(light.direction, float) @ R
        lv = geom.unit_axes @ (lw / np.linalg.norm(lw))
        h = lv + view
        h /= max(np.linalg.norm(h), 1e-12)
        rows.append([*lv, *h, *(light.intensity * np.asarray(light.color, float))])
    lights = np.asarray(rows, dtype=np.float64).reshape(-1, 9)
    # white lights: r, g and b factors are equal, one diffuse and one specular factor per code will do
    white = bool(np.all(lights[:, 6:9] == lights[:, 6:7]))
    out = np.empty((65536, 2 if white else 6), dtype=dtype)
    normals = decode_lut()
    args = (float(shading.ambient), float(shading.diffuse), float(shading.specular), float(shading.shininess),
            bool(shading.two_sided))
    # the codes are independent: share them out between the threads (the kernel releases the GIL)
    cuts = np.linspace(0, normals.shape[0], max(1, threads) + 1).astype(int)
    parts = [(normals[a:b], out[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]
    if len(parts) == 1:
        shade_codes(normals, lights, *args, out)
    else:
        list(_pool(threads).map(lambda p: shade_codes(p[0], lights, *args, p[1]), parts))
    return out


GATHER_SLAB = 8      # k-slices read at a time when gathering channel values


@functools.lru_cache(maxsize=8)
def _tile_pixels(h: int, w: int, tile: int) -> np.ndarray:
    """Pixels in each tile of an h x w image (edge tiles are smaller)."""
    rows = np.minimum(tile, h - np.arange(0, h, tile))
    cols = np.minimum(tile, w - np.arange(0, w, tile))
    out = np.outer(rows, cols).astype(np.int32)
    out.flags.writeable = False
    return out


def gather_channels(aug, loaded: dict, channels, geom) -> dict:
    """Read, for every loaded index axis, the channel values of just its voxels.

    Channels are read in slabs of k-slices and only the slabs that hold a voxel of interest are read, so a
    scene that sees a small part of the volume reads a small part of the file; the values come out in the
    order of each axis's ``positions``, so the renderer reads them sequentially.
    """
    from .splat.kernels import flat_indices

    n_k, n_j, n_i = geom.shape
    plane = n_i * n_j
    flat_stride = (1, n_i, plane)
    fis = {}
    for ax, la in loaded.items():
        ia, ib, ic = cam_mod.SLICE_AXES[ax]
        strides = np.array([flat_stride[ia], flat_stride[ib], flat_stride[ic]], dtype=np.int64)
        fis[ax] = flat_indices(la.slice_block_ptr, la.block_voxel_ptr, la.positions, la.n_a, strides)
    out = {ax: {} for ax in loaded}
    if not channels or not fis:
        return out
    all_fi = np.concatenate(list(fis.values()))
    order = np.argsort(all_fi, kind="stable")
    sorted_fi = all_fi[order]
    bounds = np.searchsorted(sorted_fi, np.arange(0, n_k + GATHER_SLAB, GATHER_SLAB) * plane)
    for ch in channels:
        vals = np.empty(all_fi.shape[0], dtype=np.uint16 if ch == "normal" else np.uint8)
        for s_i, k0 in enumerate(range(0, n_k, GATHER_SLAB)):
            lo, hi = bounds[s_i], bounds[s_i + 1]
            if hi > lo:
                slab = aug.read(ch, k0, min(n_k, k0 + GATHER_SLAB)).ravel()
                vals[order[lo:hi]] = slab[sorted_fi[lo:hi] - k0 * plane]
        start = 0
        for ax, fi in fis.items():
            out[ax][ch] = vals[start:start + fi.shape[0]]
            start += fi.shape[0]
    return out


def cut_coefficients(cuts, geom, axis, dtype=np.float64) -> np.ndarray:
    """Cutting planes as rows (g0, ga, gb, gc) in slice coordinates: keep ``g0 + a ga + b gb + c gc >= 0``."""
    ia, ib, ic = cam_mod.SLICE_AXES[axis]
    S = geom.steps
    rows = []
    for cut in cuts:
        n = np.asarray(cut.normal, float)
        rows.append([(geom.q - np.asarray(cut.point, float)) @ n, S[ia] @ n, S[ib] @ n, S[ic] @ n])
    return np.asarray(rows, dtype=dtype).reshape(-1, 4)


class Renderer:
    """Holds what a scene needs in memory and renders its views."""

    def __init__(self, scene, views=None, method: str | None = None):
        self.scene = scene
        self.views = tuple(scene.views if views is None else views)
        self.method = method or scene.render.method
        self.threads = scene.render.threads or default_threads()
        self.report = LoadReport()
        self.aug = open_augmented(scene.data.augmented)
        ro = scene.render
        self.dtype = np.float64 if ro.precision == "float64" else np.float32
        sp = scene.volume.spacing or self.aug.spacing_ijk
        from .scene import spacing_problem
        if spacing_problem(sp):
            raise IsplatError(f"{self.aug.path}: attribute 'spacing_ijk' is {list(sp)}: {spacing_problem(sp)} "
                              f"(or set volume.spacing in the scene)")
        self.geom = cam_mod.volume_geometry(self.aug.shape, sp, scene.volume.origin, scene.volume.axes)
        self.luts = build_luts(scene.transfer, self.aug.gradient_magnitude_scale)
        self.unit = scene.transfer.unit_distance or float(self.geom.spacing.min())
        self.report.intervals = self.luts.intervals.tolist()
        W, H = scene.image.width, scene.image.height
        self.frames = [cam_mod.view_frame(c, self.geom, W, H) for c in self.views]
        self.axes_needed = sorted({cam_mod.principal_axis(f, self.geom)[0] for f in self.frames})
        self.report.axes = list(self.axes_needed)
        self._load()

    # ---- loading: only what the scene uses -------------------------------------------------------------
    def _load(self):
        scene, aug = self.scene, self.aug
        empty = len(self.luts.intervals) == 0
        self.use_shade = bool(scene.shading.enabled) and not empty
        self.use_gm = self.luts.gradient is not None and not empty
        channels = (["normal"] if self.use_shade else []) + (["gradient_magnitude"] if self.use_gm else [])
        self.report.channels = list(channels)
        self.loaded, self.attrs, self.selected = {}, {}, {}
        if self.method == "full":
            # every voxel is visited: whole channels, indexed by flat position
            self.dens = aug.read("density").ravel() if not empty else _EMPTY_U8
            if not empty:
                self.report.channels.insert(0, "density")
            whole = {ch: aug.read(ch).ravel() for ch in channels}
            for ax in self.axes_needed:
                self.attrs[ax] = (whole.get("gradient_magnitude", _EMPTY_U8), whole.get("normal", _EMPTY_U16))
        elif self.method == "indexed":
            self.dens = _EMPTY_U8
            if scene.data.index is None:
                raise IsplatError("scene: data.index is required for render.method = 'indexed'")
            from .index import open_index

            idx = open_index(scene.data.index)
            if tuple(idx.shape) != tuple(aug.shape) or idx.density_sha256 != aug.density_sha256:
                raise IsplatError(f"{scene.data.index}: index was built from another volume "
                                  f"(density_sha256 {idx.density_sha256[:12]}..., {aug.path.name} has "
                                  f"{aug.density_sha256[:12]}...); rebuild it with isplat index")
            if not empty:
                from .splat.kernels import select_voxels

                ivs = self.luts.intervals.astype(np.int64)
                for ax in self.axes_needed:
                    la = idx.load_axis(ax, [tuple(map(int, iv)) for iv in ivs])
                    if max(la.n_a, la.n_b) > 65535:
                        raise IsplatError(f"{scene.data.index}: axis {ax} slices are {la.n_a}x{la.n_b}; "
                                          "the renderer takes at most 65535 voxels per in-slice axis")
                    try:
                        self.selected[ax] = select_voxels(la.slice_block_ptr, la.block_density,
                                                          la.block_voxel_ptr, la.positions, ivs, la.n_a, la.n_b)
                    except ValueError as exc:
                        raise IsplatError(f"{scene.data.index}: axis {ax}: {exc}") from None
                    self.loaded[ax] = la
                gathered = gather_channels(aug, self.loaded, channels, self.geom)
                for ax in self.axes_needed:
                    # values in the selection's order (grouped by cell)
                    g, src = gathered[ax], self.selected[ax][6]
                    self.attrs[ax] = (g["gradient_magnitude"][src] if "gradient_magnitude" in g else _EMPTY_U8,
                                      g["normal"][src] if "normal" in g else _EMPTY_U16)
                    self.selected[ax] = self.selected[ax][:6]
                # the decoded blocks have served: frames need only the selection and the gathered values
                self.report.index_decoded_bytes = int(sum(
                    la.slice_block_ptr.nbytes + la.block_density.nbytes + la.block_voxel_ptr.nbytes
                    + la.positions.nbytes for la in self.loaded.values()))
                self.loaded = {}
            self.report.index_bytes = int(idx.bytes_read)
        else:
            raise IsplatError(f"render.method = {self.method!r}: expected 'indexed' or 'full'")
        self.report.augmented_bytes = int(aug.bytes_read)

    def held_bytes(self) -> int:
        """Bytes of volume data this renderer keeps for its frames (selection, gathered values, channels)."""
        arrays = [self.dens] + [a for pair in self.attrs.values() for a in pair]
        arrays += [a for sel in self.selected.values() for a in sel]
        seen, total = set(), 0
        for a in arrays:
            if a.size > 1 and id(a) not in seen:        # the full method shares channels between axes
                seen.add(id(a))
                total += a.nbytes
        return total

    # ---- one view ---------------------------------------------------------------------------------------
    def render_view(self, view_index: int = 0, et: float | None = None):
        """Render view ``view_index``; returns (rgba float array (H, W, 4), FrameStats)."""
        from .splat.kernels import TILE, render_axis

        t0 = time.perf_counter()
        scene, geom, ro = self.scene, self.geom, self.scene.render
        frame = self.frames[view_index]
        axis, sign = cam_mod.principal_axis(frame, geom)
        H, W = frame.height, frame.width
        img = np.zeros((H, W, 4), dtype=self.dtype)
        examined = splatted = slices = 0
        if len(self.luts.intervals):
            ia, ib, ic = cam_mod.SLICE_AXES[axis]
            n_kji = geom.shape
            n_ijk = (n_kji[2], n_kji[1], n_kji[0])
            flat_stride = (1, n_ijk[0], n_ijk[0] * n_ijk[1])        # strides of i, j, k in [k, j, i]
            strides = np.array([flat_stride[ia], flat_stride[ib], flat_stride[ic]], dtype=np.int64)
            n_a, n_b = n_ijk[ia], n_ijk[ib]
            order = cam_mod.slice_order(frame, geom, axis, sign)
            proj = cam_mod.projection(frame, geom, axis)
            fp = make_footprint(proj.jac, ro.footprint_sigma, ro.footprint_radius, ro.footprint_table, self.dtype)
            persp = frame.projection == "perspective"
            if persp:
                atab = alpha_table(self.luts, None)
                unit_c = geom.unit_axes[ic]
                normal_off = float((geom.q - frame.e) @ unit_c)
                slice_step = float(geom.spacing[ic])
                inv_unit = slice_step / self.unit
                qe = geom.q - frame.e
            else:
                atab = alpha_table(self.luts, proj.ds / self.unit)
                normal_off, slice_step, inv_unit, qe = 0.0, 1.0, 1.0, np.zeros(3)
            shade = (shade_table(scene.shading, frame, geom, threads=self.threads) if self.use_shade
                     else np.zeros((1, 6), np.float32))
            cuts = cut_coefficients(scene.cuts, geom, axis)
            ntx, nty = -(-W // TILE), -(-H // TILE)
            tile_npix = _tile_pixels(H, W, TILE)
            sheet = np.zeros((H, W, 4), dtype=self.dtype)
            et_val = ro.early_termination if et is None else et
            gm, nrm = self.attrs[axis]
            if self.method == "indexed":
                args = self.selected[axis]
            else:
                args = (np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int32),
                        np.zeros(1, np.uint16), np.zeros(1, np.uint16), _EMPTY_U8)
            common = (self.method == "full", *args,
                      self.dens, gm, self.use_gm, nrm, self.use_shade, strides, n_a, n_b,
                      atab, self.luts.color, shade, persp, inv_unit, normal_off, slice_step,
                      proj.coef, proj.steps, qe, cuts, fp.table, fp.params,
                      img, sheet, np.zeros((H, W), np.uint8), np.zeros((nty, ntx), np.int32), tile_npix,
                      np.zeros((H, W), np.uint8))
            bands = _bands(nty, self.threads)
            per_band = [np.zeros(3, dtype=np.int64) for _ in bands]

            dirty_lists = [np.empty(H * W + 1, np.int64) for _ in bands]

            def run(bi, part):
                y0, y1 = bands[bi]
                render_axis(part, *common, dirty_lists[bi], self.dtype(et_val), per_band[bi],
                            y0 * TILE, min(H, y1 * TILE))

            # with a progress bar (stderr is a terminal), the slices go in chunks so the bar can move;
            # the kernel's state (image, saturation) carries over from one chunk to the next
            parts = np.array_split(order, 20) if progress.enabled() and len(order) >= 40 else [order]
            for part in progress.bar(parts, desc=f"slices ({len(order)})", unit="chunk", disable=len(parts) == 1):
                if len(bands) == 1:
                    run(0, part)
                else:
                    list(_pool(self.threads).map(run, range(len(bands)), [part] * len(bands)))
            # every band examines every voxel: count them once; one band counts each splatted voxel
            examined = int(per_band[0][0])
            splatted = sum(int(b[1]) for b in per_band)
            slices = max(int(b[2]) for b in per_band)
        out = composite_background(img, scene.image.background)
        return out, FrameStats(axis, sign, examined, splatted, slices, time.perf_counter() - t0)


def composite_background(img: np.ndarray, background) -> np.ndarray:
    """Premultiplied RGBA over the background colour -> straight RGBA (float)."""
    from .splat.kernels import finish

    out = np.empty(img.shape, dtype=img.dtype)
    if not finish(img, np.asarray(background, dtype=np.float64), out):
        raise IsplatError("render produced non-finite pixels; please report this scene")
    return out


def default_threads() -> int:
    """Cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


_POOLS: dict = {}


def _pool(n: int):
    from concurrent.futures import ThreadPoolExecutor

    if n not in _POOLS:
        _POOLS[n] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="isplat")
    return _POOLS[n]


def _bands(n_tile_rows: int, threads: int):
    """Split the tile rows into one band per thread (each band traverses every slice, so more bands
    would repeat the traversal; the splatting is what the bands share out)."""
    nb = 1 if threads <= 1 else min(n_tile_rows, threads)
    edges = np.linspace(0, n_tile_rows, nb + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]
