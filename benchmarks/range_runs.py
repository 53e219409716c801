"""Post's channels ordered by their neighbourhood's density range (issue 26): ``python -m benchmarks.range_runs
[--quick] [--cases H1,E2,...] [--bins 8,16,64x16,...]`` prints tables (not a docs page). A count, not a timing; no
change to isplat or its formats.

Result (full cases, `--bins` default, 2026-11-28; read = this layout + post's index reads of today, against post's
bytes needed; today's bricks: H1 2.23, E2 2.68, B1 1.42, H1-512 1.64, C1 2.04; pages 1.73-5.67). The runs read hold
about the footprint (1.0-1.12x the needed voxels at a fitting B); what decides is the positions: a 4-byte index
alone makes 1.75-2.1x; ``adaptive`` brick positions cost least (then spans and bitmaps), and they grow with the
number of runs. The bins are fixed when the file is written, and one binning must serve every scene: the threshold
scenes want few lo bins (1x8, union key: H1 1.18, E2 1.28, B1 1.11, H1-512 1.10) but C1's 51..81 veil needs fine lo
bins (1x8: 2.50, it reads half the volume; 64: 1.27). With one binning for all five: ``union`` (one file, any view)
at B = 64: H1 1.45, E2 1.56, B1 1.33, H1-512 1.25, C1 1.27 (64x16: 1.44, 1.55, 1.28, 1.24, 1.25): E2 misses 1.5 by a
little; ``axis`` (a file per view axis, 3x the disk) at 64x16: 1.38, 1.37, 1.26, 1.23, 1.19, all met. Pages / needed
equal read / needed within 0.01 except E2 (+0.2: the index's pages). But neither key holds what today's sampler
reads: it samples whole 4 x 4 cells (1.15-1.29x the needed voxels); at those B the read set must grow by 13-26%. The
quads reading the voxels left out are all transparent (benchmarks/test_range_runs.py, run by make bench-check; no
labels, no taps between thick slices), so a sampler that skipped quads with a corner not loaded would draw the same image; today's would read
missing voxels. The ``cells`` key holds them (checked) at 64x16: H1 1.75, E2 1.90, B1 1.35, H1-512 1.37, C1 1.49
(best binning per case: 1.46, 1.62, 1.25, 1.25, 1.49): H1 and E2 fail. File (union, 64, adaptive): 1.06-1.17x the
augmented file (idx4: 1.9-2x). Pre from the same file (positions + normals; its voxels of interest and order still
from the index) reads 1.21-1.43x its needed at its best binning (1x8/1x32) and 1.41-2.03 at 64 or 64x16, against
1.00-1.14 from the values file: positions cost about as much as its 2 B of normals, so one layout cannot serve pre
at its bar of 1.3; /values stays for pre.

Bins cut by the data (branch rangebins, 2026-11-28; ``--post-only --keys union``): one file for every view meets
1.5 in every row when its bins are few and cut by the volume's keys. ``dpLOxHI``, the cut of least mean read / ideal
over every interval [t0, t1], 1 <= t0 <= t1 <= 255 (volume only, no transfer function), at 8 x 8 (64 runs): H1
1.19, E2 1.45, B1 1.18, H1-512 1.16, C1 1.26 (adaptive; pages 1.20, 1.64, 1.19, 1.16, 1.26: E2's index pages);
16 x 16: 1.31, 1.46, 1.25, 1.22, 1.26; 64 x 16: 1.39, 1.62, 1.35, 1.28, 1.30 (uniform 64 x 16: 1.44, 1.55, 1.28,
1.24, 1.25). Fewer runs win: the voxels read change little with the cut (the scenes' intervals start at the
histogram's material boundaries, where the cut puts its edges), the positions shrink with the runs. Uniform bins
that few fail C1 (16 x 16: 2.56, its veil inside one lo bin); equal-count (``q``) cuts are worse than uniform:
they spend their bins where the voxels are and leave the rare high codes coarse (E2 q64x16: hi 177..246 one bin;
2.86). File (dp8x8, adaptive) / augmented file: 1.03-1.09. Other scenes (scripts/range_spread.py: voxels read /
the key's ideal over every interval holding 1/1000 of the volume, H1, E2, B1, C1): dp16x16 median 1.02-1.03, 90th
percentile 1.10-1.14; dp8x8 1.03-1.07, 1.19-1.29; uniform 64 x 16 1.01-1.03, 1.78-3.78 (its 16 hi bins). Few
bins fitted to the volume are not fitted to these five scenes only.

The ``union`` key and the ``dp`` cut are isplat.runs' (moved there for the runs file, formats/runs.md, which
``isplat index`` writes with dp8x8 bins); this module imports them.

Method. For each voxel, key = (lo, hi), the least and greatest density over the voxels whose quads it shares.
Three keys: ``union``, the in-slice 3 x 3 squares of the three slice axes united (19 voxels: the 3 x 3 x 3 cube
without its 8 corners; one file serves every view); ``axis``, the 3 x 3 square of the view's axis alone (one file
per axis); ``cells``, what today's sampler reads: it samples every quad of a 4 x 4 cell holding a voxel of
interest and its neighbours' last column and row (isplat.splat.post._mark_cells), so it reads voxels
a0 - 1 .. a0 + 4 of the cell at a0 (in a and b); voxel a is read when a cell of interest lies among its
*cell window* (a - 4 .. a + 3 at a % 4 == 0, a - 1 .. a + 2, a - 2 .. a + 1, a - 3 .. a + 4 at a % 4 == 3), and
the key is over those windows, the three axes united. The bilinear field of a quad spans exactly [least corner,
greatest corner], so a scene needs a voxel only if its range meets an interval of non-zero opacity.

Bins cut by the data (``qLOxHI``, ``dpLOxHI``; the bins are fixed when the file is written, so from the volume's
keys alone): every pair (lo bin, hi bin) a run, as LOxHI, with bin edges at any code. ``q``: equal-count bins of
the lo and of the hi codes over all voxels (a code above its share a bin alone). ``dp``: the edges that minimise
the sum over every interval [t0, t1] (1 <= t0 <= t1 <= 255) of the voxels read (lo below the end of t1's lo bin,
hi at or above the start of t0's hi bin) over the voxels a key with a bin per code would read: from the 2-d
histogram of (lo, hi), the lo edges exactly optimal for fixed hi edges by dynamic programming, then the hi edges
for those, four rounds from uniform bins (each round can only lower the sum). Positions are not in the objective.

Layout counted (one file, not HDF5): a 64-byte header; a run table of 24 B a run (values offset, count, positions
offset, positions bytes); runs, one per (lo bin, hi bin) with lo bin <= hi bin over B code bins (B(B + 1) / 2
runs), in hi-bin-major, lo-bin-minor order (a threshold scene reads one contiguous suffix); inside a run the
voxels in C order (k, j, i), each run's block [positions][normal 2 B][gradient magnitude 1 B][density 1 B]
(planar, so that pre reads positions and normals alone). A scene reads the table rows and blocks of the runs whose
bin rectangle can meet an interval (lo bin's least code <= interval's top and hi bin's greatest >= its bottom).
Positions, four encodings: ``idx4`` a 4-byte voxel index each; ``spans`` (start, length) u16 pairs of voxels
consecutive along i per (run, k, j) row, with a row table of 6 B (k, j, spans) per such row; ``bitmap`` per (run,
8^3 brick) holding voxels: its brick number (4 B) and a 64-byte bitmap; ``adaptive`` per (run, brick): 4 B (number
and form) and the fewer of its bitmap and 2 B a voxel (its place in the brick). ``--bins LOxHI`` (say 1x8): LO bins
of lo by HI bins of hi, every pair a run (lo bins 1: the runs of a threshold scene by hi alone). *Read* = the
layout's bytes (header, table rows, positions, values) + what post reads of the index today (its blocks and tables,
unchanged); *needed* = post's ``LoadReport.bytes_needed`` of the same scene (isplat's own count, as
``selective_read`` reports it); *pages* = distinct 4 KB pages of the layout touched (isplat.fileio.ReadCounter) +
the index's pages as today.

Pre from the same layout (issue 26 item 3, /values gone): pre still takes its voxels of interest from the index
and needs their normals. (a) runs spatial inside: pre reads positions and normals of every voxel of the runs it
selects; (b) runs ordered inside by the voxel's own density code, then spatially (sub-runs), with a u32 count per
code of the run's code span at the head of each run: pre reads those counts and the positions and normals of
the sub-runs whose code is of interest; positions per sub-run. Against pre's own ``bytes_needed``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from isplat.runs import (IN_SLICE_DIMS, Cut, cut_cost, dp_cut, interval_weights, union_key,   # noqa: F401
                         best_bins as _best_bins, bin_lut as _bin_lut, plane_ops as _plane_ops, step3 as _step3)

HEADER, TABLE_ROW, ROW_ENTRY, SPAN, BRICK_ENTRY, CODE_COUNT = 64, 24, 6, 4, 4 + 64, 4
BRICK_HEAD, LOCAL = 4, 2        # adaptive: a brick's number and form, then a bitmap or 2 B a voxel, the fewer
ENCODINGS = ("idx4", "spans", "bitmap", "adaptive")
KEYS = ("union", "axis", "cells")
BRICK = 8


def _log(msg):
    print(f"[range_runs] {msg}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------------------- keys

def _cell_window(a: np.ndarray, d: int, op) -> np.ndarray:
    """``op`` along dimension ``d`` over each voxel's cell window (module docstring): the 4-voxel cells (from 0)
    whose quads, as today's sampler marks them, read the voxel: its own cell, and the one before at a % 4 == 0,
    the one after at a % 4 == 3.

    >>> _cell_window(np.arange(10, dtype=np.uint8).reshape(1, 1, 10), 2, np.maximum).tolist()
    [[[3, 3, 3, 7, 7, 7, 7, 9, 9, 9]]]
    >>> _cell_window(np.arange(10, dtype=np.uint8).reshape(1, 1, 10), 2, np.minimum).tolist()
    [[[0, 0, 0, 0, 0, 4, 4, 4, 4, 8]]]
    """
    x = np.moveaxis(a, d, 0)
    n = x.shape[0]
    nb = -(-n // 4)
    neutral = np.iinfo(a.dtype).max if op is np.minimum else np.iinfo(a.dtype).min
    pad = np.full((nb * 4,) + x.shape[1:], neutral, dtype=a.dtype)
    pad[:n] = x
    blk = op.reduce(pad.reshape((nb, 4) + x.shape[1:]), axis=1)
    out = np.repeat(blk, 4, axis=0)[:n]
    first = np.arange(4, n, 4)
    if first.size:
        out[first] = op(out[first], blk[first // 4 - 1])
    last = np.arange(3, n, 4)
    last = last[last // 4 + 1 < nb]
    if last.size:
        out[last] = op(out[last], blk[last // 4 + 1])
    return np.ascontiguousarray(np.moveaxis(out, 0, d))


def range_key(density: np.ndarray, kind: str, axis: str = "k") -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), uint8 [k, j, i]: per voxel the least and greatest density over its ``kind`` neighbourhood
    (module docstring): ``union`` (the three axes' in-slice 3 x 3 squares united), ``axis`` (``axis``'s square
    alone), ``cells`` (the cell windows of the three axes' slices united), ``cells-axis`` (``axis``'s alone).
    ``union`` is :func:`isplat.runs.union_key`, which the runs file (formats/runs.md) uses."""
    if kind == "union":
        return union_key(density)
    step = _cell_window if kind.startswith("cells") else _step3
    planes = [IN_SLICE_DIMS[axis]] if kind in ("axis", "cells-axis") else list(IN_SLICE_DIMS.values())
    out = []
    for op in (np.minimum, np.maximum):
        acc = None
        for dims in planes:
            m = _plane_ops(density, dims, op, step)
            acc = m if acc is None else op(acc, m, out=acc)
        out.append(acc)
    return out[0], out[1]


def sampler_reads(interest: np.ndarray, axis: str) -> np.ndarray:
    """bool [k, j, i]: the voxels today's sampler reads on slices of ``axis`` (module docstring): those with a
    voxel of interest in their cell windows along both in-slice dimensions."""
    return _plane_ops(interest.view(np.uint8), IN_SLICE_DIMS[axis], np.maximum, _cell_window).view(bool)


def footprint(interest: np.ndarray, axis: str) -> np.ndarray:
    """bool [k, j, i]: post's needed voxels on slices of ``axis`` (isplat.stats.quad_footprint_per_slice)."""
    return _plane_ops(interest.view(np.uint8), IN_SLICE_DIMS[axis], np.maximum, _step3).view(bool)


# ------------------------------------------------------------------------------------------------- runs

def n_runs(bins) -> int:
    """Runs of ``bins``: B (square, lo bin <= hi bin: B(B + 1) / 2), (lo bins, hi bins) or a :class:`Cut` (every
    pair)."""
    if isinstance(bins, Cut):
        return len(bins.lo) * len(bins.hi)
    if isinstance(bins, tuple):
        return bins[0] * bins[1]
    return bins * (bins + 1) // 2


def run_of(lo: np.ndarray, hi: np.ndarray, bins) -> np.ndarray:
    """int32 [k, j, i]: each voxel's run, hi bin major, lo bin minor (square: lo bin <= hi bin).

    >>> run_of(np.array([0, 0, 64, 255]), np.array([0, 255, 200, 255]), 4).tolist()
    [0, 6, 7, 9]
    >>> run_of(np.array([0, 0, 64, 255]), np.array([0, 255, 200, 255]), (2, 4)).tolist()
    [0, 6, 6, 7]
    >>> cut = Cut(np.r_[0, 128], np.r_[0, 64, 128, 192], "")
    >>> run_of(np.array([0, 0, 64, 255]), np.array([0, 255, 200, 255]), cut).tolist()
    [0, 6, 6, 7]
    """
    if isinstance(bins, Cut):
        return _bin_lut(bins.hi)[hi] * len(bins.lo) + _bin_lut(bins.lo)[lo]
    bl, bh = bins if isinstance(bins, tuple) else (bins, bins)
    lb = lo.astype(np.int32) * bl // 256
    hb = hi.astype(np.int32) * bh // 256
    return hb * bl + lb if isinstance(bins, tuple) else hb * (hb + 1) // 2 + lb


def run_bins(bins) -> tuple[np.ndarray, np.ndarray]:
    """(lo bin, hi bin) of each run, in run order."""
    if isinstance(bins, (tuple, Cut)):
        nl = len(bins.lo) if isinstance(bins, Cut) else bins[0]
        r = np.arange(n_runs(bins))
        return r % nl, r // nl
    hb = np.repeat(np.arange(bins), np.arange(1, bins + 1))
    lb = np.arange(n_runs(bins)) - hb * (hb + 1) // 2
    return lb, hb


def _run_codes(bins) -> tuple[np.ndarray, np.ndarray]:
    """Per run, the least code of its lo bin and the greatest of its hi bin."""
    lb, hb = run_bins(bins)
    if isinstance(bins, Cut):
        hi_last = np.append(bins.hi[1:], 256) - 1
        return np.asarray(bins.lo)[lb], hi_last[hb]
    bl, bh = bins if isinstance(bins, tuple) else (bins, bins)
    wl, wh = 256 // bl, 256 // bh
    return lb * wl, hb * wh + wh - 1


def runs_meeting(intervals, bins) -> np.ndarray:
    """bool [runs]: the runs whose bin rectangle can meet one of the inclusive code ``intervals`` (with some
    lo <= hi in it)."""
    lo_first, hi_last = _run_codes(bins)
    out = np.zeros(n_runs(bins), dtype=bool)
    for t0, t1 in intervals:
        out |= (lo_first <= int(t1)) & (hi_last >= int(t0))
    return out & (lo_first <= hi_last)


# ------------------------------------------------------------------------------------------------- cuts by the data

def quantile_cut(lo: np.ndarray, hi: np.ndarray, n_lo: int, n_hi: int) -> Cut:
    """Equal-count bins: ``n_lo`` bins of the voxels' lo codes and ``n_hi`` of their hi codes, each bin about an
    equal share of the voxels (a code holding more than its share is a bin alone, and the share of the rest is
    recomputed)."""
    return Cut(_equal_count(np.bincount(lo.ravel(), minlength=256), n_lo),
               _equal_count(np.bincount(hi.ravel(), minlength=256), n_hi), f"q{n_lo}x{n_hi}")


def _equal_count(h: np.ndarray, n: int) -> np.ndarray:
    """First codes of ``n`` bins of about equal count of histogram ``h`` [256].

    >>> _equal_count(np.array([1000] + [1] * 255), 3).tolist()
    [0, 1, 129]
    """
    first, acc, rest = [0], 0, int(h.sum())
    for c in range(255):
        left = n - len(first)                        # bins still to open after this one
        if left == 0:
            break
        acc += int(h[c])
        if acc * left >= rest - acc or 255 - c <= left:   # this bin has its share, or the codes run out
            first.append(c + 1)
            rest -= acc
            acc = 0
    return np.array(first, np.int64)


def resolve(bins, lo: np.ndarray, hi: np.ndarray):
    """``bins`` as given, or a cut spec (``("q", 64, 16)``, ``("dp", 64, 16)``) cut from this key."""
    if isinstance(bins, tuple) and isinstance(bins[0], str):
        return (quantile_cut if bins[0] == "q" else dp_cut)(lo, hi, bins[1], bins[2])
    return bins


def group_stats(g: np.ndarray, n_groups: int) -> dict:
    """Per group of ``g`` (int [k, j, i], ids 0 .. n_groups - 1): its voxels, its spans of voxels consecutive
    along i, its rows (k, j) and its 8^3 bricks (each counted once per group)."""
    nk, nj, ni = g.shape
    vox = np.bincount(g.ravel(), minlength=n_groups)
    start = np.ones(g.shape, dtype=bool)
    start[:, :, 1:] = g[:, :, 1:] != g[:, :, :-1]
    spans = np.bincount(g[start], minlength=n_groups)
    rows = np.zeros(n_groups, np.int64)
    bricks = np.zeros(n_groups, np.int64)
    adaptive = np.zeros(n_groups, np.int64)
    pj, pi = -nj % BRICK, -ni % BRICK
    for k0 in range(0, nk, BRICK):
        s = g[k0:k0 + BRICK]
        rows += _distinct(s.reshape(-1, ni), n_groups)
        p = np.pad(s, ((0, BRICK - s.shape[0]), (0, pj), (0, pi)), constant_values=-1)
        p = p.reshape(BRICK, p.shape[1] // BRICK, BRICK, p.shape[2] // BRICK, BRICK).transpose(1, 3, 0, 2, 4)
        b, a = _distinct(p.reshape(-1, BRICK ** 3), n_groups, adaptive=True)
        bricks += b
        adaptive += a
    return dict(vox=vox, spans=spans, rows=rows, bricks=bricks, adaptive=adaptive)


def _distinct(rows: np.ndarray, n_groups: int, adaptive: bool = False):
    """Per group, the rows of ``rows`` (2-d) holding it (-1: no group); with ``adaptive`` also the bytes of
    those rows' adaptive positions (per row holding the group: BRICK_HEAD + the fewer of a bitmap of the row and
    LOCAL bytes per voxel of the group)."""
    s = np.sort(rows, axis=1)
    first = np.ones(s.shape, dtype=bool)
    first[:, 1:] = s[:, 1:] != s[:, :-1]
    v = s[first]
    keep = v >= 0
    n = np.bincount(v[keep], minlength=n_groups)
    if not adaptive:
        return n
    flat = np.flatnonzero(first.reshape(-1))
    count = np.diff(np.append(flat, s.size))            # each (row, group)'s voxels (rows are whole: no spill)
    cost = BRICK_HEAD + np.minimum(rows.shape[1] // 8, LOCAL * count)
    return n, np.bincount(v[keep], weights=cost[keep], minlength=n_groups).astype(np.int64)


def positions_bytes(st: dict) -> dict:
    """Bytes of each group's positions in each encoding (module docstring)."""
    return {"idx4": 4 * st["vox"], "spans": SPAN * st["spans"] + ROW_ENTRY * st["rows"],
            "bitmap": BRICK_ENTRY * st["bricks"], "adaptive": st["adaptive"]}


# ------------------------------------------------------------------------------------------------- reads

def post_read(st: dict, sel: np.ndarray, per_voxel: int) -> dict:
    """Per encoding: layout bytes post reads (header, table rows, positions, values of the runs ``sel``), the
    distinct 4 KB pages, and the file's size; ``st``: :func:`group_stats` of the runs (spatial inside)."""
    from isplat.fileio import ReadCounter

    out = {}
    n = st["vox"]
    table = HEADER + TABLE_ROW * n.size
    for enc, pos in positions_bytes(st).items():
        block = pos + 4 * n                         # every channel is stored
        off = table + np.concatenate([[0], np.cumsum(block)[:-1]])
        c = ReadCounter()
        c.touch(0, HEADER)
        for r in np.flatnonzero(sel):
            c.touch(HEADER + TABLE_ROW * int(r), TABLE_ROW)
            c.touch(int(off[r]), int(pos[r] + per_voxel * n[r]))     # [positions][normal][gm][density]
        out[enc] = dict(read=HEADER + TABLE_ROW * int(sel.sum()) + int((pos + per_voxel * n)[sel].sum()),
                        pages=c.page_bytes(), size=table + int(block.sum()), positions=int(pos[sel].sum()))
    return out


def pre_read_spatial(st: dict, sel: np.ndarray) -> dict:
    """Per encoding: what pre reads of runs spatial inside: table rows, positions and normals of runs ``sel``."""
    from isplat.fileio import ReadCounter

    out = {}
    n = st["vox"]
    table = HEADER + TABLE_ROW * n.size
    for enc, pos in positions_bytes(st).items():
        off = table + np.concatenate([[0], np.cumsum(pos + 4 * n)[:-1]])
        c = ReadCounter()
        c.touch(0, HEADER)
        for r in np.flatnonzero(sel):
            c.touch(HEADER + TABLE_ROW * int(r), TABLE_ROW)
            c.touch(int(off[r]), int(pos[r] + 2 * n[r]))
        out[enc] = dict(read=HEADER + TABLE_ROW * int(sel.sum()) + int((pos + 2 * n)[sel].sum()),
                        pages=c.page_bytes())
    return out


def code_span(bins) -> tuple[np.ndarray, np.ndarray]:
    """Per run, its codes' span [first, last]: the lo bin's first code .. the hi bin's last (empty when last <
    first)."""
    first, last = _run_codes(bins)
    return first, np.maximum(last, first - 1)


def pre_read_by_code(st: dict, bins, sel: np.ndarray, interest: np.ndarray) -> dict:
    """Per encoding: what pre reads of runs ordered inside by own code (sub-runs ``run * 256 + code``, ``st``
    their :func:`group_stats`): per run selected with a code of interest in its span, its code counts, and the
    positions and normals of its sub-runs of interest. Also post's read and the file size in this order."""
    from isplat.fileio import ReadCounter

    G = n_runs(bins)
    first, last = code_span(bins)
    counts = CODE_COUNT * (last - first + 1)
    vox = st["vox"].reshape(G, 256)
    table = HEADER + TABLE_ROW * G
    out = {}
    for enc, pos in positions_bytes(st).items():
        pos = pos.reshape(G, 256)
        pr, nr = pos.sum(1), vox.sum(1)
        block = counts + pr + 4 * nr
        off = table + np.concatenate([[0], np.cumsum(block)[:-1]])
        pcum = np.concatenate([np.zeros((G, 1), np.int64), np.cumsum(pos, 1)], 1)
        ncum = np.concatenate([np.zeros((G, 1), np.int64), np.cumsum(vox, 1)], 1)
        c = ReadCounter()
        c.touch(0, HEADER)
        read = HEADER
        for r in np.flatnonzero(sel):
            codes = np.flatnonzero(interest[first[r]:last[r] + 1]) + first[r]
            if codes.size == 0:
                continue
            c.touch(HEADER + TABLE_ROW * int(r), TABLE_ROW)
            c.touch(int(off[r]), int(counts[r]))
            read += TABLE_ROW + int(counts[r])
            for a, b in _stretches(codes):
                p0, p1 = int(off[r] + counts[r] + pcum[r, a]), int(pcum[r, b + 1] - pcum[r, a])
                n0, n1 = int(off[r] + counts[r] + pr[r] + 2 * ncum[r, a]), int(2 * (ncum[r, b + 1] - ncum[r, a]))
                for o, m in ((p0, p1), (n0, n1)):
                    if m:
                        c.touch(o, m)
                read += p1 + n1
        post = HEADER + int((TABLE_ROW + block)[sel].sum())
        out[enc] = dict(read=read, pages=c.page_bytes(), size=table + int(block.sum()), post_read=post)
    return out


def _stretches(codes: np.ndarray):
    """Maximal stretches of consecutive integers of sorted ``codes`` as (first, last).

    >>> list(_stretches(np.array([3, 4, 5, 9, 11, 12])))
    [(3, 5), (9, 9), (11, 12)]
    """
    cut = np.flatnonzero(np.diff(codes) != 1)
    starts = np.concatenate([[0], cut + 1])
    ends = np.concatenate([cut, [codes.size - 1]])
    return [(int(codes[s]), int(codes[e])) for s, e in zip(starts, ends)]


# ------------------------------------------------------------------------------------------------- measure

def reports(c: dict, work: Path, quick: bool) -> dict:
    """Post's and pre's load reports of case ``c``'s scene (its first view), as ``selective_read`` makes them."""
    from isplat.renderer import Renderer
    from isplat.scene import load_scene

    from .selective_read import _index, _scene

    idx = work / f"{c['name']}.idx.h5"
    _index(c["aug"], idx, quick)
    out = {}
    for t in ("post", "pre"):
        sc = load_scene(_scene(work, c, idx, t))
        r = Renderer(sc, (sc.views[0],), slabs=1)
        if t == "post":
            out["cells"] = {ax: len(_cell_origins(s)) for ax, s in r.selection.axes.items()}
        out[t] = r.report
    return out


def _cell_origins(s):
    from isplat.selection import cell_origins

    return cell_origins(s)[0]


def measure(c: dict, work: Path, quick: bool, bins_list, keys=KEYS, with_pre: bool = True) -> dict:
    """Every figure of case ``c`` (tables: :func:`post_rows`, :func:`pre_rows`)."""
    from isplat.augfile import open_augmented
    from isplat.stats import interest_mask

    reps = reports(c, work, quick)
    post, pre = reps["post"], reps["pre"]
    assert post.channel_bytes_per_voxel == 4, post.channels
    aug = open_augmented(c["aug"])
    density = aug.read("density")
    interest = interest_mask(post.intervals)[density]
    axis = post.needed_axis
    foot = footprint(interest, axis)
    samp = sampler_reads(interest, axis)
    cells_here = int(_cells_of_interest(interest, axis))
    base = dict(name=c["name"], axis=axis, post=post, pre=pre, n=density.size, aug_size=c["aug"].stat().st_size,
                foot=int(foot.sum()), sampler=int(samp.sum()), cells_index=reps["cells"].get(axis),
                cells_here=cells_here, rows=[], pre_rows=[])
    if base["foot"] != post.needed_voxels:
        _log(f"{c['name']}: footprint {base['foot']} here, {post.needed_voxels} in the report")
    lut = interest_mask(post.intervals)
    for key in keys:
        lo, hi = range_key(density, key, axis)
        for spec in bins_list:
            bins = resolve(spec, lo, hi)
            if isinstance(bins, Cut):
                _log(f"  {c['name']} {key} {bins.label}: lo {bins.lo.tolist()}, hi {bins.hi.tolist()}")
            runs = run_of(lo, hi, bins)
            sel = runs_meeting(post.intervals, bins)
            read_set = sel[runs]
            st = group_stats(runs, n_runs(bins))
            row = dict(key=key, bins=bins, runs_read=int(sel.sum()), runs=n_runs(bins), vox=int(read_set.sum()),
                       foot_missing=int((foot & ~read_set).sum()), sampler_missing=int((samp & ~read_set).sum()),
                       grown=int((read_set | samp).sum()), enc=post_read(st, sel, 4))
            base["rows"].append(row)
            if key == "union" and with_pre:
                pre_row = dict(bins=bins, spatial=pre_read_spatial(st, sel))
                sub = runs * 256 + density
                pre_row["by_code"] = pre_read_by_code(group_stats(sub, n_runs(bins) * 256), bins, sel, lut)
                base["pre_rows"].append(pre_row)
            _log(f"  {c['name']} {key} B={_b(bins)}: {row['vox']:,} voxels read, sampler's missing "
                 f"{row['sampler_missing']:,}")
        del lo, hi
    return base


def _cells_of_interest(interest: np.ndarray, axis: str) -> int:
    """The 4 x 4 cells (from 0, per slice of ``axis``) holding a voxel of interest."""
    m = interest
    for d in IN_SLICE_DIMS[axis]:
        x = np.moveaxis(m, d, 0)
        n = x.shape[0]
        p = np.zeros((-(-n // 4) * 4,) + x.shape[1:], bool)
        p[:n] = x
        m = np.moveaxis(p.reshape((-1, 4) + x.shape[1:]).any(axis=1), 0, d)
    return int(m.sum())


def _mb(n) -> str:
    return f"{n / 1e6:.2f}"


def post_rows(m: dict) -> list[str]:
    post = m["post"]
    need, ch_need = post.bytes_needed, post.channel_bytes_needed
    idx_b, idx_p = post.index_file_bytes, post.index_file_pages
    L = []
    for r in m["rows"]:
        e = r["enc"]
        ratios = " / ".join(f"{(e[k]['read'] + idx_b) / need:.2f}" for k in ENCODINGS)
        ch = " / ".join(f"{e[k]['read'] / ch_need:.2f}" for k in ENCODINGS)
        pages = " / ".join(f"{(e[k]['pages'] + idx_p) / need:.2f}" for k in ENCODINGS)
        pos = " / ".join(_mb(e[k]["positions"]) for k in ENCODINGS)
        size = " / ".join(f"{e[k]['size'] / m['aug_size']:.2f}" for k in ENCODINGS)
        holds = "yes" if r["sampler_missing"] == 0 else \
            f"no: {r['sampler_missing']:,} missing (read set x{r['grown'] / max(1, r['vox']):.3f})"
        L.append(f"| {m['name']} | {r['key']} | {_b(r['bins'])} | {r['runs_read']} / {r['runs']} | {r['vox']:,} | "
                 f"{_mb(4 * r['vox'])} | {pos} | {_mb(e['spans']['read'] + idx_b)} | {_mb(need)} | **{ratios}** | "
                 f"{ch} | {pages} | {size} | {holds} |")
    return L


POST_HEAD = ["| case | key | B | runs read | voxels read | values (MB) | positions idx4 / spans / bitmap / "
             "adaptive (MB) | read, spans (MB) | needed (MB) | read / needed idx4 / spans / bitmap / adaptive | "
             "channels only: layout / channel bytes needed | pages / needed | file / augmented file | "
             "holds today's sampler's reads |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]


def pre_rows(m: dict) -> list[str]:
    pre = m["pre"]
    need, idx_b, idx_p = pre.bytes_needed, pre.index_file_bytes, pre.index_file_pages
    L = []
    for r in m["pre_rows"]:
        cells = []
        for kind in ("spatial", "by_code"):
            e = r[kind]
            cells.append(" / ".join(f"{(e[k]['read'] + idx_b) / need:.2f}" for k in ENCODINGS))
            cells.append(" / ".join(f"{(e[k]['pages'] + idx_p) / need:.2f}" for k in ENCODINGS))
        post_need = m["post"].bytes_needed
        bc = r["by_code"]
        post_bc = " / ".join(f"{(bc[k]['post_read'] + m['post'].index_file_bytes) / post_need:.2f}"
                             for k in ENCODINGS)
        size = " / ".join(f"{bc[k]['size'] / m['aug_size']:.2f}" for k in ENCODINGS)
        L.append(f"| {m['name']} | {_b(r['bins'])} | {_mb(need)} | {pre.read_ratio:.2f} | {cells[0]} | {cells[1]} | "
                 f"**{cells[2]}** | {cells[3]} | {post_bc} | {size} |")
    return L


PRE_HEAD = ["| case | B | pre needed (MB) | pre today (values file) read / needed | runs spatial: read / needed "
            "idx4 / spans / bitmap / adaptive | pages / needed | runs by own code: read / needed | pages / needed | "
            "post from runs by own code: read / needed | file (by code) / augmented |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.range_runs", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="volumes at 1/4 resolution")
    ap.add_argument("--cases", default="H1,E2,B1,H1-512,C1")
    ap.add_argument("--bins", default="8,16,32,64,1x8,1x32,4x32,64x8,64x16,q64x16,dp64x16,dp32x32,dp16x16,dp8x8",
                    help="B (square), LOxHI, or cut by the volume's keys: qLOxHI (equal-count), dpLOxHI (least "
                         "read over every interval), comma-separated")
    ap.add_argument("--keys", default=",".join(KEYS), help="of " + ", ".join(KEYS))
    ap.add_argument("--post-only", action="store_true", help="no rows of pre from the same layout")
    a = ap.parse_args(argv)
    from .selective_read import cases

    try:
        bins_list = [_bins(b) for b in a.bins.split(",")]
    except ValueError:
        print(f"range_runs: error: --bins {a.bins!r}: give B or LOxHI, each a power of two up to 256, or qLOxHI / "
              f"dpLOxHI, each 1 to 256", file=sys.stderr)
        return 2
    keys = a.keys.split(",")
    if not set(keys) <= set(KEYS):
        print(f"range_runs: error: --keys {a.keys!r}: give some of {', '.join(KEYS)}", file=sys.stderr)
        return 2
    done = []
    with tempfile.TemporaryDirectory(prefix="isplat-ranges-") as t:
        work = Path(t)
        for c in cases(work, a.quick, only=a.cases.split(",")):
            _log(f"{c['name']}: {c['what']}")
            done.append(measure(c, work, a.quick, bins_list, keys, not a.post_only))
            if c["aug"].parent == work:
                c["aug"].unlink()
    print(summary(done))
    return 0


def _bins(text: str):
    """``"16"`` -> 16 (square, lo bin <= hi bin), ``"4x32"`` -> (4, 32) (lo bins, hi bins), ``"dp64x16"`` ->
    ("dp", 64, 16) (a cut by the data, :func:`resolve`).

    >>> _bins("16"), _bins("4x32"), _bins("q48x20")
    (16, (4, 32), ('q', 48, 20))
    """
    for how in ("dp", "q"):
        if text.lower().startswith(how):
            parts = [int(x) for x in text[len(how):].lower().split("x")]
            if len(parts) != 2 or any(p < 1 or p > 256 for p in parts):
                raise ValueError(text)
            return (how, parts[0], parts[1])
    parts = [int(x) for x in text.lower().split("x")]
    if len(parts) > 2 or any(p < 1 or p > 256 or 256 % p for p in parts):
        raise ValueError(text)
    return parts[0] if len(parts) == 1 else tuple(parts)


def _b(bins) -> str:
    if isinstance(bins, Cut):
        return bins.label
    return f"{bins[0]}x{bins[1]}" if isinstance(bins, tuple) else str(bins)


def summary(done) -> str:
    L = ["Cases (post, view axis): voxels needed (footprint), voxels today's sampler reads, cells of interest "
         "(here / the index's), post today read / needed.", "",
         "| case | axis | volume voxels | needed voxels | sampler reads | cells here / index | post today |",
         "|---|---|---:|---:|---:|---:|---:|"]
    for m in done:
        L.append(f"| {m['name']} | {m['axis']} | {m['n']:,} | {m['foot']:,} | {m['sampler']:,} | "
                 f"{m['cells_here']:,} / {m['cells_index']:,} | {m['post'].read_ratio:.2f} |")
    L += ["", "Post from range runs (read = layout + index as today):", "", *POST_HEAD]
    for m in done:
        L += post_rows(m)
    L += ["", "Pre from the same layout (union key; read = layout + index as today; no values file):", "", *PRE_HEAD]
    for m in done:
        L += pre_rows(m)
    return "\n".join(L)


if __name__ == "__main__":
    sys.exit(main())
