"""Placing runs read from a runs file (formats/runs.md §5) into a pool (a row of 8^3 voxels per brick read,
isplat.selection.WholeChannels): one compiled pass over a span of consecutive runs that checks every brick number,
count, position byte, place and density before any array is indexed with it, and marks each voxel placed (a voxel
placed twice is refused).

The kernel returns an error record instead of raising (compiled code cannot name the file); :func:`message`
turns it into the one line :class:`isplat.errors.IsplatError` carries. tests/test_runs.py checks the kernel
against tests/runs_reference.py's decoding, the slow NumPy reference.
"""

from __future__ import annotations

import numpy as np

from .jit import jit, leaf, stage

BRICK = 8
BRICK_VOXELS = 512
BITMAP_BYTES = 64       # version 1: above V1_LIST_MAX voxels, a 64-byte bitmap, else 2 B a voxel (version 2: masks)
V1_LIST_MAX = 32

# a byte of a mask or a bitmap: how many bits it has set, and which (least significant first)
BIT_COUNT = np.array([bin(m).count("1") for m in range(256)], dtype=np.int64)
BIT_PLACES = np.array([[t for t in range(8) if m >> t & 1] + [0] * (8 - bin(m).count("1")) for m in range(256)],
                      dtype=np.int64)

OK, NOT_INCREASING, BEYOND_GRID, COUNT_RANGE, COUNT_SUM, POSITION_BYTES, BITMAP_COUNT, PLACE, OUTSIDE, DENSITY, \
    TWICE, POINTERS, EMPTY_MASK = range(13)
PLACE_FAULT, MASK_FAULT = 1 << 20, 1 << 21      # :func:`_places`' faults below these


@leaf
def _fail(err, code, r, b, x, y):
    err[0], err[1], err[2], err[3], err[4] = code, r, b, x, y
    return True


@leaf
def _brick_bytes(pdata, q, end, c, version):
    """Bytes of the positions of a brick of ``c`` voxels from byte ``q`` (formats/runs.md §4; ``version`` the
    file's), or -1 when they would pass byte ``end`` (its run's end): version 2's masks, 1 + a byte per plane set
    in the plane mask + a byte per row set in those planes' row masks (each mask read only once it is known to
    lie before ``end``); version 1's from ``c``, a bitmap's 64 or a list's 2 a voxel."""
    if version == 1:
        n = BITMAP_BYTES if c > V1_LIST_MAX else 2 * c
        return n if q + n <= end else -1
    if q >= end:
        return -1
    planes = BIT_COUNT[pdata[q]]
    if q + 1 + planes > end:
        return -1
    n = 1 + planes
    for y in range(planes):
        n += BIT_COUNT[pdata[q + 1 + y]]
    return n if q + n <= end else -1


@leaf
def _check_run(r, bp, pp, vp, num, cnt, pdata, n_bricks, version, at, err):
    """Run ``r``'s bricks before any is placed: pointers in bounds, brick numbers strictly increasing and within
    the grid, counts 1..512 summing to the run's voxels, its bricks' position bytes (:func:`_brick_bytes`) as
    many as the run's; per brick ``g``, its run, first voxel and first position byte into ``at[:, g]`` (valid
    when the run checks out)."""
    if not (0 <= bp[r] <= bp[r + 1] <= num.shape[0] and 0 <= pp[r] <= pp[r + 1] <= pdata.shape[0]
            and 0 <= vp[r] <= vp[r + 1]):
        return _fail(err, POINTERS, r, 0, 0, 0)
    voxels, q, bad_range, beyond = 0, pp[r], -1, -1
    for g in range(bp[r], bp[r + 1]):
        if g > bp[r] and num[g] <= num[g - 1]:
            return _fail(err, NOT_INCREASING, r, g - bp[r], 0, 0)
        c = np.int64(cnt[g])
        if bad_range < 0 and (c < 1 or c > BRICK_VOXELS):
            bad_range = g
        if beyond < 0 and np.int64(num[g]) >= n_bricks:
            beyond = g
        at[0, g], at[1, g], at[2, g] = r, vp[r] + voxels, q
        voxels += c
        if q >= 0:
            n = _brick_bytes(pdata, q, pp[r + 1], c, version)
            q = q + n if n >= 0 else -1
    if voxels != vp[r + 1] - vp[r]:
        return _fail(err, COUNT_SUM, r, 0, voxels, vp[r + 1] - vp[r])
    if bad_range >= 0:
        return _fail(err, COUNT_RANGE, r, bad_range - bp[r], cnt[bad_range], 0)
    if q != pp[r + 1]:
        return _fail(err, POSITION_BYTES, r, 0, pp[r + 1] - pp[r], q - pp[r] if q >= 0 else -1)
    if beyond >= 0:
        return _fail(err, BEYOND_GRID, r, beyond - bp[r], num[beyond], n_bricks)
    return False


@leaf
def _places(pdata, q, c, buf, mask, version):
    """Decode the places of a brick of ``c`` voxels whose positions start at byte ``q`` into ``buf[:c]``
    (increasing) and, but for a list, into the eight words of bits ``mask`` (:func:`_brick_mask`): its masks
    (:func:`_mask_places`); version 1: a bitmap (more than V1_LIST_MAX voxels) or a list of uint16. Returns 0,
    or -(the places found) for masks or a bitmap whose voxels are not ``c`` (the count found so far when it is
    above), -(1 + PLACE_FAULT + place) for a list's place not below 512 or not above the one before it,
    -(1 + MASK_FAULT + m) for a plane (m = dk) or row (m = 8 + dk * 8 + dj) set without a bit below it."""
    if version != 1:
        return _mask_places(pdata, q, c, buf, mask)
    if c > V1_LIST_MAX:
        have = 0
        for w in range(8):
            mask[w] = 0
        for byte in range(BITMAP_BYTES):
            m = pdata[q + byte]
            if m == 0:
                continue
            mask[byte >> 3] |= np.uint64(m) << np.uint64(8 * (byte & 7))
            if have + BIT_COUNT[m] > c:
                return -(have + BIT_COUNT[m])
            for t in range(BIT_COUNT[m]):
                buf[have + t] = 8 * byte + BIT_PLACES[m, t]
            have += BIT_COUNT[m]
        return 0 if have == c else -have
    last = -1
    for t in range(c):
        place = np.int64(pdata[q + 2 * t]) | np.int64(pdata[q + 2 * t + 1]) << 8
        if place >= BRICK_VOXELS or place <= last:
            return -(1 + PLACE_FAULT + place)
        buf[t] = last = place
    return 0


@leaf
def _mask_places(pdata, q, c, buf, mask):
    """:func:`_places` of version 2's masks from byte ``q``: the plane mask (bit dk: plane dk holds a voxel),
    then a row mask for each plane set (bit dj: row (dk, dj) holds one), then a voxel mask for each row set (bit
    di: the voxel at place (dk * 8 + dj) * 8 + di), each in order (:func:`_brick_bytes` has checked that they lie
    in the run's bytes); each voxel mask is also the byte ``row % 8`` of word ``row // 8`` of ``mask``. At most
    64 rows of 8 voxels: ``buf`` holds 512 + 8 places (the last row writes eight), the count is checked at the
    end (the places found when it is not ``c``)."""
    for w in range(8):
        mask[w] = 0
    planes = pdata[q]
    row_at = q + 1
    at = q + 1 + BIT_COUNT[planes]
    have = 0
    for s in range(BIT_COUNT[planes]):
        dk = BIT_PLACES[planes, s]
        rows = pdata[row_at]
        row_at += 1
        if rows == 0:
            return -(1 + MASK_FAULT + dk)
        for u in range(BIT_COUNT[rows]):
            row = dk * 8 + BIT_PLACES[rows, u]
            m = pdata[at]
            at += 1
            if m == 0:
                return -(1 + MASK_FAULT + 8 + row)
            mask[row >> 3] |= np.uint64(m) << np.uint64(8 * (row & 7))
            for t in range(8):              # all eight (a fixed count, no branch): those past the row's are
                buf[have + t] = 8 * row + BIT_PLACES[m, t]      # written over by the next row's, or unused
            have += BIT_COUNT[m]
    return 0 if have == c else -have


@stage
def _bricks_of(bp, pp, vp, num, cnt, pdata, n_bricks, version, err):
    """Every run's bricks checked (:func:`_check_run`) and, per brick of the span, its run and its first voxel
    and position byte (int64[3, bricks]); on a fault, ``err`` set and an empty table."""
    at = np.zeros((3, num.shape[0]), dtype=np.int64)
    for r in range(bp.shape[0] - 1):
        if _check_run(r, bp, pp, vp, num, cnt, pdata, n_bricks, version, at, err):
            return at[:, :0]
    return at


@jit
def mask_runs(bp, pp, vp, num, cnt, pdata, shape, table, loaded, version):
    """The first pass of placing a span of runs (arguments as :func:`place_runs`'): every run checked
    (:func:`_check_run`) and each brick's mask ORed into ``loaded`` (the rows' layout), nothing placed: the bits
    :func:`pack_rows` packs the rows by before :func:`place_runs` places the voxels at the packed rows' bases. A
    brick's own faults (its places, a voxel outside the volume or in two runs, a density) are
    :func:`place_runs`' to find (its masks may set such bits here; the file is then refused there). Returns
    :func:`place_runs`' error record and the checked bricks' table (:func:`_bricks_of`; :func:`place_runs` takes
    it for the same arrays instead of checking them again)."""
    err = np.zeros(5, dtype=np.int64)
    gj, gi = (shape[1] + 7) // 8, (shape[2] + 7) // 8
    if table.shape[0] != (shape[0] + 7) // 8 * gj * gi or loaded.shape[0] % 8 \
            or pp[pp.shape[0] - 1] > pdata.shape[0] or cnt.shape[0] < num.shape[0]:
        _fail(err, POINTERS, 0, 0, 0, 0)
        return err, np.zeros((3, 0), dtype=np.int64)
    at = _bricks_of(bp, pp, vp, num, cnt, pdata, table.shape[0], version, err)
    if err[0]:
        return err, at
    buf = np.empty(BRICK_VOXELS + 8, dtype=np.int64)
    mask = np.empty(8, dtype=np.uint64)
    for g in range(num.shape[0]):
        row = np.int64(table[np.int64(num[g])])
        if row == 0 or 8 * row + 8 > loaded.shape[0]:
            _fail(err, POINTERS, at[0, g], g - bp[at[0, g]], 0, 0)     # a pool without this brick's row
            return err, at
        if version != 1:
            _mask_words(pdata, at[2, g], mask)
        else:
            c = np.int64(cnt[g])
            if _places(pdata, at[2, g], c, buf, mask, version) < 0:
                continue                                    # (place_runs refuses it)
            if c <= V1_LIST_MAX:
                for w in range(8):
                    mask[w] = 0
                for t in range(c):
                    mask[buf[t] >> 6] |= np.uint64(1) << np.uint64(buf[t] & 63)
        for w in range(8):
            loaded[8 * row + w] |= mask[w]
    return err, at


@leaf
def _mask_words(pdata, q, mask):
    """Version 2's masks of the brick whose positions start at byte ``q`` as eight words of bits (``mask``, as
    :func:`_mask_places` makes them, without the places; :func:`_check_run` has checked that they lie in the
    run's bytes)."""
    for w in range(8):
        mask[w] = 0
    planes = pdata[q]
    row_at = q + 1
    at = q + 1 + BIT_COUNT[planes]
    for s in range(BIT_COUNT[planes]):
        rows = pdata[row_at]
        row_at += 1
        for u in range(BIT_COUNT[rows]):
            row = BIT_PLACES[planes, s] * 8 + BIT_PLACES[rows, u]
            mask[row >> 3] |= np.uint64(pdata[at]) << np.uint64(8 * (row & 7))
            at += 1


@jit
def place_runs(bp, pp, vp, lo, hi, num, cnt, pdata, dens, nrm, gm, shape, table, loaded, bases, pos, out_d, out_n,
               out_g, version, checked):
    """Runs ``0 .. len(bp) - 2`` of a span (``bp``, ``pp``, ``vp``: int64 pointers into this span's brick, position
    byte and voxel arrays; ``lo``, ``hi``: each run's least and greatest code) placed into a pool: ``table``
    (each brick's row, isplat.selection.WholeChannels; the caller gives every brick of the runs one) and
    ``bases`` (int64, each row's first place: ``row * 512``, or a packed pool's, :func:`pack_rows`) put the
    voxel at place ``p`` of its brick at ``q = bases[row] + p``; its bit is set in ``loaded`` (the rows' layout:
    uint64 words, bit ``s % 64`` of word ``s // 64`` for ``s = row * 512 + p``), its density, normal and
    gradient magnitude go to ``out_d[q]``, ``out_n[q]``, ``out_g[q]`` (each skipped when of size 0; ``nrm``,
    ``gm`` of the span's size when their outputs are not), and its flat position ``i + n_i * (j + n_j * k)`` to
    ``pos[v]`` (unless ``pos`` is empty). ``shape``: int64 (n_k, n_j, n_i). ``version``: the file's format
    version (the positions' forms, formats/runs.md §4). ``checked``: :func:`mask_runs`' table of these same
    arrays' bricks, or int64[3, 0] to check them here (:func:`_bricks_of`).
    Returns int64[5]: (0, ...) when every run checked out, else (code, run, brick of the run, x, y) of a fault
    (:func:`message`). Run after run, a brick's checks a word of 64 voxels at a time (:func:`_brick_mask`); the
    voxel loops then only copy. Placing on two threads measured no faster on this 2-core machine with another
    process busy (437 against 392 ms, whole-shape channels): memory-bound."""
    err = np.zeros(5, dtype=np.int64)
    nk, nj, ni = shape[0], shape[1], shape[2]
    gj, gi = (nj + 7) // 8, (ni + 7) // 8
    nout = max(out_d.shape[0], out_n.shape[0], out_g.shape[0])
    if vp[vp.shape[0] - 1] > dens.shape[0] or (pos.shape[0] and pos.shape[0] < vp[vp.shape[0] - 1]) \
            or table.shape[0] != (nk + 7) // 8 * gj * gi or loaded.shape[0] % 8 \
            or bases.shape[0] * 8 != loaded.shape[0] or _sizes_differ(nout, out_d, out_n, out_g) \
            or pp[pp.shape[0] - 1] > pdata.shape[0] \
            or cnt.shape[0] < num.shape[0] or (out_n.shape[0] and nrm.shape[0] < dens.shape[0]) \
            or (out_g.shape[0] and gm.shape[0] < dens.shape[0]):
        _fail(err, POINTERS, 0, 0, 0, 0)
        return err
    at = checked
    if checked.shape[1] != num.shape[0] or num.shape[0] == 0:
        at = _bricks_of(bp, pp, vp, num, cnt, pdata, table.shape[0], version, err)
    if err[0]:
        return err
    buf = np.empty(BRICK_VOXELS + 8, dtype=np.int64)         # (_mask_places writes eight past the last place)
    mask = np.empty(8, dtype=np.uint64)
    for g in range(num.shape[0]):
        r = at[0, g]
        if _place_brick(r, g - bp[r], np.int64(num[g]), np.int64(cnt[g]), at[1, g], at[2, g], lo[r], hi[r], pdata,
                        dens, nrm, gm, shape, buf, mask, table, loaded, bases, nout, pos, out_d, out_n, out_g,
                        version, err):
            break
    return err


@leaf
def _sizes_differ(n, out_d, out_n, out_g):
    """Whether an output (not of size 0) differs from ``n`` places (the largest output's)."""
    d, m, g = out_d.shape[0], out_n.shape[0], out_g.shape[0]
    return (d != 0 and d != n) or (m != 0 and m != n) or (g != 0 and g != n)


@leaf
def _place_brick(r, b, n, c, v, q, lo_r, hi_r, pdata, dens, nrm, gm, shape, buf, mask, table, loaded, bases, nout,
                 pos, out_d, out_n, out_g, version, err):
    """Brick ``b`` of run ``r`` (brick number ``n``, ``c`` voxels from the span's voxel ``v``, positions from
    byte ``q``) decoded (into ``buf``), checked (:func:`_brick_mask`, the densities within the run's codes) and
    placed (:func:`place_runs`); True on a fault (then in ``err``)."""
    got = _places(pdata, q, c, buf, mask, version)
    if got < -MASK_FAULT:
        return _fail(err, EMPTY_MASK, r, b, -got - 1 - MASK_FAULT, 0)
    if got < -PLACE_FAULT:
        return _fail(err, PLACE, r, b, -got - 1 - PLACE_FAULT, 0)
    if got < 0:
        return _fail(err, BITMAP_COUNT, r, b, -got, c)
    row = np.int64(table[n])
    if row == 0 or 8 * row + 8 > loaded.shape[0] or bases[row] < 0 or (nout and bases[row] + BRICK_VOXELS > nout):
        return _fail(err, POINTERS, r, b, 0, 0)             # a pool without this brick's row (the caller's)
    bad = _brick_mask(buf, c, n, shape, row, loaded, mask, version == 1 and c <= V1_LIST_MAX)
    if bad >= 0:
        code = OUTSIDE if bad >> 62 else TWICE
        k, j, i = _voxel(n, bad & 511, shape)
        x = k * 1_000_000_000_000 + j * 1_000_000 + i if code == OUTSIDE else i + shape[2] * (j + shape[1] * k)
        return _fail(err, code, r, b, x, 0)                 # (OUTSIDE: (k, j, i) in one)
    for t in range(c):
        d = dens[v + t]
        if d < lo_r or d > hi_r:
            return _fail(err, DENSITY, r, b, d, 0)
    for w in range(8):
        loaded[8 * row + w] |= mask[w]
    base = bases[row]
    if out_d.shape[0]:
        for t in range(c):
            out_d[base + buf[t]] = dens[v + t]
    if out_n.shape[0]:
        for t in range(c):
            out_n[base + buf[t]] = nrm[v + t]
    if out_g.shape[0]:
        for t in range(c):
            out_g[base + buf[t]] = gm[v + t]
    if pos.shape[0]:
        for t in range(c):
            k, j, i = _voxel(n, buf[t], shape)
            pos[v + t] = i + shape[2] * (j + shape[1] * k)
    return False


@leaf
def _voxel(n, place, shape):
    """(k, j, i) of place ``place`` of brick ``n`` of ``shape``'s grid of 8^3 bricks."""
    gj, gi = (shape[1] + 7) // 8, (shape[2] + 7) // 8
    return (n // (gj * gi) * BRICK + (place >> 6), n // gi % gj * BRICK + (place >> 3 & 7),
            n % gi * BRICK + (place & 7))


@leaf
def _brick_mask(buf, c, n, shape, row, loaded, mask, from_list):
    """The brick's places ``buf[:c]`` as eight words of bits (``mask``, made by :func:`_places` but for a list:
    ``from_list``, made here); -1 when every place lies in the volume and none is loaded already, else the first
    place that does not (``| 1 << 62`` when outside the volume)."""
    if from_list:
        for w in range(8):
            mask[w] = 0
        for t in range(c):
            mask[buf[t] >> 6] |= np.uint64(1) << np.uint64(buf[t] & 63)
    k0, j0, i0 = _voxel(n, 0, shape)
    ek, ej, ei = min(shape[0] - k0, 8), min(shape[1] - j0, 8), min(shape[2] - i0, 8)
    clash = False
    for w in range(8):
        clash = clash or (loaded[8 * row + w] & mask[w]) != 0
    if not clash and ek == 8 and ej == 8 and ei == 8:
        return -1
    for t in range(c):                      # (a fault, or a brick on the volume's edge)
        p = buf[t]
        if (p >> 6) >= ek or (p >> 3 & 7) >= ej or (p & 7) >= ei:
            return p | (1 << 62)
        if loaded[8 * row + (p >> 6)] >> np.uint64(p & 63) & np.uint64(1):
            return p
    return -1


# ---- packing a pool's rows -------------------------------------------------------------------------------------
# How far back from the packed pool's top, in words of 64 places, a row's first fit is sought (:func:`pack_rows`):
# on the head's bone (H1) 256 packs the rows into 1.58 places a voxel of interest (a row each: 2.45; a search of
# the whole pool: 1.49, 15-35x the time) in about 1 ms (docs/design.md, "A packed pool").
PACK_WINDOW = 256
FULL_WORD = np.uint64(0xFFFFFFFFFFFFFFFF)


def pack_rows(loaded: np.ndarray, window: int = PACK_WINDOW) -> tuple[np.ndarray, int]:
    """Where each row of a pool goes in a packed pool whose rows share places: ``(bases, places)``, int64 per
    row (its first place; row 0, which holds no voxel, 0) and the packed pool's length (at least a row's). Rows
    are laid in order, each at the first place, a multiple of 64 from ``window`` words below the pool's top on,
    where none of its loaded voxels (``loaded``: uint64 words, 8 a row, bit ``q % 64`` of word ``q // 64`` for
    place ``q`` of the rows' layout, :meth:`isplat.runsfile.RunsFile.place`) meets another row's. A row keeps
    its eight words' order, so the voxel at place ``p`` of row ``r`` is at ``bases[r] + p``."""
    if loaded.dtype != np.uint64 or loaded.ndim != 1 or loaded.size % 8:
        raise ValueError(f"loaded bits: expected uint64 words, 8 a row, got {loaded.dtype} {loaded.shape}")
    bases = np.zeros(loaded.size // 8, dtype=np.int64)
    top = _pack(loaded, max(int(window), 0), bases)
    return bases, max(64 * top, BRICK_VOXELS)


@jit
def _pack(loaded, window, bases):
    """:func:`pack_rows`' first fit, the pool's occupied places as words of bits; returns the words used."""
    n = loaded.shape[0] // 8
    occ = np.zeros(8 * n + 8, dtype=np.uint64)
    first = 0                   # the first word with a free place
    top = 0
    for r in range(1, n):
        f0 = 0
        while f0 < 8 and loaded[8 * r + f0] == 0:
            f0 += 1
        if f0 == 8:
            continue
        d = max(first - f0, top - window, 0)
        while not _fits(occ, loaded, r, d, f0):
            d += 1
        for u in range(f0, 8):
            occ[d + u] |= loaded[8 * r + u]
        bases[r] = 64 * d
        top = max(top, d + 8)
        while occ[first] == FULL_WORD:
            first += 1
    return top


@leaf
def _fits(occ, loaded, r, d, f0):
    """Whether row ``r``'s words from ``f0`` on, laid from word ``d``, meet no occupied place."""
    for u in range(f0, 8):
        if occ[d + u] & loaded[8 * r + u]:
            return False
    return True


def _mask_name(m: int) -> str:
    """Plane dk (m = dk) or row (dk, dj) (m = 8 + dk * 8 + dj) of :func:`_mask_places`' fault."""
    return f"plane {m}" if m < 8 else f"row ({(m - 8) // 8}, {(m - 8) % 8}) (dk, dj)"


def message(err, first_run: int, shape, lo, hi, version: int) -> tuple[str, str]:
    """``(dataset, text)`` (text from its separator on) of :func:`place_runs`' error record ``err`` (runs numbered
    from ``first_run``; ``lo``, ``hi`` the span's runs' codes): the dataset at fault and what is wrong, for one
    line of IsplatError."""
    code, r, b, x, y = (int(e) for e in err)
    run = f", run {first_run + r}"
    forms = "counts" if version == 1 else "masks"
    grid = int(np.prod([-(-int(n) // BRICK) for n in shape]))
    if code == OUTSIDE:
        x = f"({x // 10 ** 12}, {x // 10 ** 6 % 10 ** 6}, {x % 10 ** 6})"
    return {
        POINTERS: ("run_voxel_ptr", f"{run}: offsets beyond the arrays read"),
        NOT_INCREASING: ("brick_number", f"{run}: brick numbers not strictly increasing"),
        BEYOND_GRID: ("brick_number", f"{run}: brick number {x}, beyond the {grid} bricks of shape {tuple(shape)}"),
        COUNT_RANGE: ("positions", f"{run}: brick {b} of the run has {x} voxels, expected 1 to 512"),
        COUNT_SUM: ("brick_voxel_count", f"{run}: the bricks hold {x} voxels, 'runs/run_voxel_ptr' gives the run {y}"),
        POSITION_BYTES: ("positions", f"{run}: {x} bytes of positions, the bricks' {forms} make "
                                      f"{y if y >= 0 else 'more'}"),
        BITMAP_COUNT: ("positions", f"{run}: brick {b} of the run: its positions hold {x} voxels, its count says "
                                    f"{y}"),
        EMPTY_MASK: ("positions", f"{run}: brick {b} of the run: {_mask_name(x)} is set in its masks but holds "
                                  f"no voxel"),
        PLACE: ("positions", f"{run}: brick {b} of the run: place {x}, expected places below 512, strictly "
                             f"increasing within the brick"),
        OUTSIDE: ("brick_number", f"{run}: voxel {x} (k, j, i) of brick {b} of the run lies outside the volume of "
                                  f"shape {tuple(shape)}"),
        DENSITY: ("density", f"{run}: a density outside the run's codes {int(lo[r])}..{int(hi[r])}"),
        TWICE: ("positions", f": voxel {x} (flat) lies in two runs"),
    }[code]


def unpool(table: np.ndarray, bases: np.ndarray, loaded: np.ndarray, shape, pools) -> tuple[list, np.ndarray]:
    """A packed pool's channels whole-shape (flat ``[k, j, i]``, zeros where no voxel is held) and the bits of
    the voxels held in that layout (uint64 words, bit ``f % 64`` of word ``f // 64`` for flat index ``f``, as
    isplat.splat.post.loaded_bits gives them). ``table``: each brick's row (uint32, C order of the 8^3 grid of
    ``shape``, 0: none); ``bases``, ``loaded``: the rows' first places and their loaded bits (:func:`pack_rows`);
    ``pools``: the channels' pools (an empty one stays empty). The pool is isplat's own (placed and checked by
    :func:`place_runs`); its tables are checked against each other before the kernel indexes with them."""
    shape = tuple(int(n) for n in shape)
    grid_n = tuple(-(-n // BRICK) for n in shape)
    rows = bases.shape[0]
    if (table.size != int(np.prod(grid_n)) or loaded.size != 8 * rows or rows == 0
            or int(table.max(initial=0)) >= rows or int(bases.min()) < 0
            or any(p.size and int(bases.max()) + BRICK_VOXELS > p.size for p in pools)):
        raise ValueError(f"a pool of {rows} rows, {loaded.size} words of bits and a table of {table.size} bricks "
                         f"does not fit shape {shape} and pools of {[p.size for p in pools]} places")
    n = int(np.prod(shape, dtype=np.int64))
    outs = [np.zeros(n if p.size else 0, p.dtype) for p in pools]
    words = np.zeros((n + 63) // 64, np.uint64)
    _unpool(table, bases, loaded, np.asarray(shape, np.int64), *pools, *outs, words)
    return outs, words


@jit
def _unpool(table, bases, loaded, shape, p0, p1, p2, o0, o1, o2, words):
    """:func:`unpool`'s pass: brick by brick, each loaded place of its row to its flat index."""
    nk, nj, ni = shape[0], shape[1], shape[2]
    gj, gi = (nj + BRICK - 1) // BRICK, (ni + BRICK - 1) // BRICK
    for t in range(table.shape[0]):
        row = np.int64(table[t])
        if row == 0:
            continue
        k0, j0, i0 = t // (gj * gi) * BRICK, t // gi % gj * BRICK, t % gi * BRICK
        base = bases[row]
        for p in range(BRICK_VOXELS):
            if (loaded[8 * row + (p >> 6)] >> np.uint64(p & 63)) & np.uint64(1) == 0:
                continue
            k, j, i = k0 + (p >> 6), j0 + (p >> 3 & 7), i0 + (p & 7)
            if k >= nk or j >= nj or i >= ni:
                continue                    # (no voxel is placed there: formats/runs.md §5 refuses it)
            f = (k * nj + j) * ni + i
            q = base + p
            if o0.shape[0] > 0:
                o0[f] = p0[q]
            if o1.shape[0] > 0:
                o1[f] = p1[q]
            if o2.shape[0] > 0:
                o2[f] = p2[q]
            words[f >> 6] |= np.uint64(1) << np.uint64(f & 63)
