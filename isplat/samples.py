"""Deterministic synthetic volumes for demos, tests and benchmarks.

``make_sample(name, shape=None, seed=0) -> (array[k, j, i], spacing_ijk)``. Solids are painted in order
(later primitives overwrite earlier ones, so a bore is a primitive painted with the air value) with an
anti-aliased edge two voxels wide, which gives the partial-volume ramps a scanner would and hence smooth
gradients for shading. Noise is Gaussian from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .jit import jit
from .errors import IsplatError

# primitive kinds
ELLIPSOID, CYLINDER, BOX = 0, 1, 2
# width of the partial-volume ramp at a surface, in voxels: wide enough that central differences give
# smooth normals (a one-voxel ramp leaves ~6 degrees of staircase error), narrow enough to stay sharp
EDGE = 2.0

DEFAULT_SHAPES = {  # (n_i, n_j, n_k), as the paper quotes sizes
    "head": (256, 256, 225),
    "engine": (256, 256, 110),
    "marschner-lobb": (41, 41, 41),
    "sphere": (32, 32, 32),
    "two-density-cube": (32, 32, 32),
    "ct-head": (256, 256, 225),
    "ct-chest": (256, 192, 160),
    "mr-head": (256, 256, 225),
}
NAMES = tuple(DEFAULT_SHAPES)
# the samples that stand for a patient, as a DICOM series with the identity orientation would be: i towards the
# patient's left, j posterior (the face at -j), k superior (isplat.orientation; `isplat sample` records it in .nrrd
# and prints `--orientation LPS` in the augment command of a .npy or .raw)
ORIENTATIONS = {"head": "LPS", "ct-head": "LPS", "ct-chest": "LPS", "mr-head": "LPS"}
DTYPES = {"head": "uint16", "engine": "uint8", "marschner-lobb": "float32", "sphere": "float32",
          "two-density-cube": "uint8", "ct-head": "int16", "ct-chest": "int16", "mr-head": "uint16"}


@jit(parallel=True)
def _paint(vol, kinds, params, values, edge):
    """Paint primitives in order into ``vol[k, j, i]`` (float32) with a linear edge ``edge`` voxels wide.

    ``params[p]`` = centre (ci, cj, ck), half sizes (hi, hj, hk) in voxels, axis (cylinders), all as float64.
    Coverage ``t = clip(0.5 - sd / edge, 0, 1)`` with ``sd`` an approximate signed distance in voxels.
    """
    nk, nj, ni = vol.shape
    for p in range(kinds.shape[0]):
        ci, cj, ck = params[p, 0], params[p, 1], params[p, 2]
        hi, hj, hk = params[p, 3], params[p, 4], params[p, 5]
        kind = kinds[p]
        axis = int(params[p, 6])
        val = values[p]
        if kind == CYLINDER:  # radius in the two axes other than `axis`, half length along it
            r = hi
            ext = (r, r, r)
            if axis == 0:
                ext = (hk, r, r)
            elif axis == 1:
                ext = (r, hk, r)
            else:
                ext = (r, r, hk)
            ei, ej, ek = ext
        else:
            ei, ej, ek = hi, hj, hk
        k0 = max(0, int(math.floor(ck - ek - edge - 1)))
        k1 = min(nk, int(math.ceil(ck + ek + edge + 2)))
        j0 = max(0, int(math.floor(cj - ej - edge - 1)))
        j1 = min(nj, int(math.ceil(cj + ej + edge + 2)))
        i0 = max(0, int(math.floor(ci - ei - edge - 1)))
        i1 = min(ni, int(math.ceil(ci + ei + edge + 2)))
        for k in numba.prange(k0, k1):
            z = k - ck
            for j in range(j0, j1):
                y = j - cj
                for i in range(i0, i1):
                    x = i - ci
                    if kind == ELLIPSOID:
                        q2 = (x / hi) ** 2 + (y / hj) ** 2 + (z / hk) ** 2
                        q = math.sqrt(q2)
                        g = math.sqrt((x / hi**2) ** 2 + (y / hj**2) ** 2 + (z / hk**2) ** 2)
                        # distance ~ (q - 1) / |grad q|, |grad q| = g / q
                        sd = (q - 1.0) * q / g if g > 0 else -min(hi, min(hj, hk))
                    elif kind == BOX:
                        sd = max(abs(x) - hi, max(abs(y) - hj, abs(z) - hk))
                    else:
                        if axis == 0:
                            rr, ll = math.sqrt(y * y + z * z), abs(x)
                        elif axis == 1:
                            rr, ll = math.sqrt(x * x + z * z), abs(y)
                        else:
                            rr, ll = math.sqrt(x * x + y * y), abs(z)
                        sd = max(rr - hi, ll - hk)
                    t = 0.5 - sd / edge
                    if t <= 0.0:
                        continue
                    if t >= 1.0:
                        vol[k, j, i] = val
                    else:
                        vol[k, j, i] = vol[k, j, i] * (1.0 - t) + val * t


def _prims(shape_ijk, items):
    """Turn primitives in normalised coordinates ([-1, 1] per axis) into voxel parameters for `_paint`."""
    n = np.asarray(shape_ijk, dtype=np.float64)
    half = n / 2.0
    centre = (n - 1) / 2.0
    kinds, params, values = [], [], []
    for kind, c, h, axis, val in items:
        c = centre + np.asarray(c, dtype=np.float64) * half
        if kind == CYLINDER:
            # radius scaled by the mean in-plane half size, half length along the axis
            others = [a for a in range(3) if a != axis]
            r = h[0] * float(np.mean(half[others]))
            hl = h[1] * half[axis]
            hh = (r, 0.0, hl)
        else:
            hh = tuple(np.asarray(h, dtype=np.float64) * half)
        kinds.append(kind)
        params.append([*c, *hh, float(axis)])
        values.append(val)
    return (np.asarray(kinds, dtype=np.int64), np.asarray(params, dtype=np.float64),
            np.asarray(values, dtype=np.float32))


def _painted(shape_ijk, background, items):
    ni, nj, nk = shape_ijk
    vol = np.full((nk, nj, ni), background, dtype=np.float32)
    _paint(vol, *_prims(shape_ijk, items), EDGE)
    return vol


def _add_noise(vol, sigma, seed, lo, hi):
    """Add N(0, sigma) noise slab by slab in float32 and clip to [lo, hi] (in place)."""
    rng = np.random.default_rng(seed)
    step = max(1, (1 << 22) // max(1, vol[0].size))
    for k0 in range(0, vol.shape[0], step):
        s = vol[k0:k0 + step]
        s += rng.standard_normal(s.shape, dtype=np.float32) * np.float32(sigma)
        np.clip(s, lo, hi, out=s)
    return vol


# CT-like values, uint16 = Hounsfield + 1024; air is exactly 0, the lowest value
AIR, CSF, BRAIN, EYE, SOFT, BONE, TOOTH = 0.0, 1030.0, 1060.0, 1040.0, 1100.0, 2200.0, 2600.0


# the head's primitives: (kind, centre (i, j, k), half sizes or (radius, half length), axis, value); the face is
# at -j, the top at +k
_HEAD_ITEMS = [
    (CYLINDER, (0.0, 0.05, -0.85), (0.42, 0.25), 2, SOFT),            # neck
    (ELLIPSOID, (0.0, 0.0, 0.05), (0.72, 0.90, 0.88), 0, SOFT),        # scalp / skin
    (ELLIPSOID, (0.0, 0.0, 0.07), (0.67, 0.85, 0.83), 0, BONE),        # skull, outer table
    (ELLIPSOID, (0.0, 0.0, 0.09), (0.60, 0.78, 0.76), 0, BRAIN),       # brain (inside the skull)
    (ELLIPSOID, (-0.11, 0.02, 0.18), (0.07, 0.22, 0.12), 0, CSF),      # lateral ventricles
    (ELLIPSOID, (0.11, 0.02, 0.18), (0.07, 0.22, 0.12), 0, CSF),
    (ELLIPSOID, (0.0, 0.12, 0.02), (0.03, 0.06, 0.05), 0, CSF),        # third ventricle
    (ELLIPSOID, (0.0, -0.35, 0.25), (0.05, 0.04, 0.05), 0, 1075.0),    # small lesion-like blob
    (CYLINDER, (0.0, 0.25, -0.62), (0.09, 0.22), 2, BONE),            # cervical spine
    (CYLINDER, (0.0, 0.25, -0.62), (0.04, 0.23), 2, CSF),             # spinal canal
    (ELLIPSOID, (0.0, -0.62, -0.55), (0.40, 0.22, 0.10), 0, BONE),     # jaw
    (ELLIPSOID, (0.0, -0.66, -0.48), (0.30, 0.14, 0.05), 0, TOOTH),    # teeth
    (ELLIPSOID, (-0.27, -0.72, -0.12), (0.11, 0.11, 0.10), 0, EYE),    # eyes
    (ELLIPSOID, (0.27, -0.72, -0.12), (0.11, 0.11, 0.10), 0, EYE),
    (ELLIPSOID, (0.0, -0.70, -0.28), (0.10, 0.10, 0.10), 0, AIR),      # nasal cavity
    (ELLIPSOID, (-0.62, 0.05, -0.20), (0.05, 0.05, 0.05), 0, AIR),     # ear canals
    (ELLIPSOID, (0.62, 0.05, -0.20), (0.05, 0.05, 0.05), 0, AIR),
]


def _head(shape, seed):
    vol = _painted(shape, AIR, _HEAD_ITEMS)
    _add_noise(vol, 3.0, seed, 0.0, 65535.0)
    np.rint(vol, out=vol)
    return vol.astype(np.uint16), (1.0, 1.0, 1.0)


# Hounsfield units of the CT samples (typical published values, rounded)
HU = {"air": -1000.0, "lung": -850.0, "fat": -100.0, "csf": 10.0, "brain": 35.0, "soft": 45.0, "blood": 50.0,
      "contrast": 350.0, "bone": 1200.0, "tooth": 1800.0, "metal": 3000.0}


def _head_hu_items():
    """The head sample's primitives in Hounsfield units, plus contrast-filled carotids and a metal filling."""
    E, C = ELLIPSOID, CYLINDER
    to_hu = {AIR: HU["air"], CSF: HU["csf"], BRAIN: HU["brain"], EYE: HU["csf"], SOFT: HU["soft"],
             BONE: HU["bone"], TOOTH: HU["tooth"], 1075.0: HU["blood"]}
    items = [(kind, c, h, axis, to_hu[val]) for kind, c, h, axis, val in _HEAD_ITEMS]
    items += [
        (C, (-0.20, -0.05, -0.80), (0.045, 0.22), 2, HU["contrast"]),   # carotid arteries, with contrast
        (C, (0.20, -0.05, -0.80), (0.045, 0.22), 2, HU["contrast"]),
        (E, (0.12, -0.74, -0.47), (0.04, 0.03, 0.03), 0, HU["metal"]),  # a metal dental filling
    ]
    return items


def _ct_head(shape, seed):
    """The head in Hounsfield units (int16): air -1000 with noise, clipped at the scanner's -1024."""
    vol = _painted(shape, HU["air"], _head_hu_items())
    _add_noise(vol, 5.0, seed, -1024.0, 3071.0)
    np.rint(vol, out=vol)
    return vol.astype(np.int16), (1.0, 1.0, 1.0)


def _ct_chest_items():
    """The chest's primitives, in painting order (the next paints over the last)."""
    E, C = ELLIPSOID, CYLINDER
    return [
        (C, (0.0, 0.0, 0.0), (0.90, 1.0), 2, HU["fat"]),                 # body (subcutaneous fat)
        (C, (0.0, 0.0, 0.0), (0.82, 1.0), 2, HU["soft"]),                # chest wall muscle
        (E, (-0.40, 0.0, 0.05), (0.33, 0.55, 0.85), 0, HU["lung"]),      # lungs
        (E, (0.40, 0.0, 0.05), (0.33, 0.55, 0.85), 0, HU["lung"]),
        (E, (0.05, -0.25, -0.15), (0.22, 0.30, 0.35), 0, HU["blood"]),   # heart (unenhanced wall)
        (C, (0.05, 0.30, 0.0), (0.07, 1.0), 2, HU["contrast"]),          # descending aorta with contrast
        (C, (0.0, 0.58, 0.0), (0.18, 1.0), 2, HU["bone"]),               # spine
        (C, (0.0, 0.58, 0.0), (0.06, 1.0), 2, HU["csf"]),                # spinal canal
    ]


# the ct-chest sample's solids as labels, in the order of _ct_chest_items (the body's fat and the chest wall are
# ids 1 and 2; LPS: i towards the patient's left, so the lung at -i is the right lung)
CT_CHEST_LABELS = ("body", "chest_wall", "lung_right", "lung_left", "heart", "aorta", "spine", "spinal_canal")


def _ct_chest(shape, seed):
    """A chest CT in Hounsfield units: fat and muscle wall, two lungs, heart, contrast-filled aorta, spine."""
    vol = _painted(shape, HU["air"], _ct_chest_items())
    _add_noise(vol, 8.0, seed, -1024.0, 3071.0)
    np.rint(vol, out=vol)
    return vol.astype(np.int16), (1.0, 1.0, 1.5)


# T1-weighted MRI signal (arbitrary scanner units): fat brightest, white matter > grey matter, CSF and bone dark
T1 = {"background": 0.0, "scalp": 900.0, "bone": 60.0, "csf": 120.0, "grey": 420.0, "white": 620.0, "eye": 150.0}


def _mr_head(shape, seed, background=0.0):
    """A T1 MRI head: the head sample's geometry with T1 signal, white matter inside grey, noise on top.
    ``background`` > 0: every voxel raised by it and the air's noise widened to ``background / 8`` (a template's
    or a scanner's offset, as the MNI152 template's 350-550 around the head)."""
    E = ELLIPSOID
    to_t1 = {AIR: T1["background"], CSF: T1["csf"], BRAIN: T1["grey"], EYE: T1["eye"], SOFT: T1["scalp"],
             BONE: T1["bone"], TOOTH: T1["bone"], 1075.0: T1["grey"]}
    items = [(kind, c, h, axis, to_t1[val]) for kind, c, h, axis, val in _HEAD_ITEMS]
    items.insert(4, (E, (0.0, 0.0, 0.12), (0.45, 0.60, 0.55), 0, T1["white"]))   # white matter
    vol = _painted(shape, T1["background"], items)
    if background > 0:
        air = vol == T1["background"]
        noise = np.random.default_rng(seed + 1).normal(0.0, background / 8.0, size=int(air.sum()))
        vol[air] += noise.astype(np.float32)
        vol += np.float32(background)
    _add_noise(vol, 5.0, seed, -1e9, 1e9)
    np.abs(vol, out=vol)                       # magnitude images: Rician-like background
    np.rint(vol, out=vol)
    return vol.astype(np.uint16), (1.0, 1.0, 1.0)


def _engine(shape, seed):
    E, C, B = ELLIPSOID, CYLINDER, BOX
    AL, STEEL, BOLT = 90.0, 160.0, 235.0
    items = [
        (B, (0.0, 0.0, -0.1), (0.80, 0.55, 0.60), 0, AL),            # block
        (B, (0.0, 0.0, 0.55), (0.60, 0.35, 0.12), 0, AL),            # head deck
        (C, (-0.45, 0.0, 0.15), (0.26, 0.80), 2, STEEL),              # cylinder liners
        (C, (0.0, 0.0, 0.15), (0.26, 0.80), 2, STEEL),
        (C, (0.45, 0.0, 0.15), (0.26, 0.80), 2, STEEL),
        (C, (-0.45, 0.0, 0.15), (0.19, 0.90), 2, AIR),                # bores
        (C, (0.0, 0.0, 0.15), (0.19, 0.90), 2, AIR),
        (C, (0.45, 0.0, 0.15), (0.19, 0.90), 2, AIR),
        (C, (0.0, 0.40, -0.35), (0.07, 0.95), 0, AIR),                # oil gallery channel along i
        (C, (0.0, -0.40, -0.35), (0.05, 0.95), 0, AIR),               # coolant channel
        (B, (0.0, 0.0, -0.62), (0.70, 0.40, 0.06), 0, AIR),           # crankcase slot
        (C, (0.62, -0.42, -0.45), (0.08, 0.45), 2, BOLT),             # bolts (E2: ~1 % of voxels)
        (C, (-0.62, -0.42, -0.45), (0.08, 0.45), 2, BOLT),
        (C, (0.62, 0.42, -0.45), (0.08, 0.45), 2, BOLT),
        (C, (-0.62, 0.42, -0.45), (0.08, 0.45), 2, BOLT),
    ]
    vol = _painted(shape, AIR, items)
    _add_noise(vol, 2.0, seed, 0.0, 255.0)
    np.rint(vol, out=vol)
    return vol.astype(np.uint8), (1.0, 1.0, 1.0)


def _marschner_lobb(shape, fm=6.0, alpha=0.25):
    """Marschner & Lobb (1994) test signal on [-1, 1]^3, sampled at both ends of each axis."""
    ni, nj, nk = shape
    x = np.linspace(-1, 1, ni, dtype=np.float64)[None, None, :]
    y = np.linspace(-1, 1, nj, dtype=np.float64)[None, :, None]
    z = np.linspace(-1, 1, nk, dtype=np.float64)[:, None, None]
    r = np.sqrt(x * x + y * y)
    rho_r = np.cos(2 * np.pi * fm * np.cos(np.pi * r / 2))
    v = (1 - np.sin(np.pi * z / 2) + alpha * (1 + rho_r)) / (2 * (1 + alpha))
    spacing = tuple(2.0 / max(1, n - 1) for n in shape)
    return v.astype(np.float32), spacing


def _sphere(shape, dtype):
    ni, nj, nk = shape
    rad = 0.7 * min(shape) / 2
    vol = _painted(shape, 0.0, [(ELLIPSOID, (0, 0, 0), tuple(rad / (n / 2) for n in shape), 0, 1.0)])
    if dtype == "uint8":
        return np.rint(vol * 255).astype(np.uint8)
    return vol


def _two_density_cube(shape, dtype):
    """A cube filling the middle half of each axis: density 100 where i < n_i/2, 200 elsewhere; air 0."""
    ni, nj, nk = shape
    vol = np.zeros((nk, nj, ni), dtype=np.uint8)
    sl = tuple(slice(n // 4, n - n // 4) for n in (nk, nj, ni))
    vol[sl] = 100
    vol[sl[0], sl[1], ni // 2:ni - ni // 4] = 200
    return vol.astype(np.float32) / 255 if dtype == "float32" else vol


def make_sample_labels(name: str, shape=None) -> tuple[np.ndarray, dict[int, str]]:
    """The painted solids of sample ``name`` as a label map (uint8 ``[k, j, i]``: each voxel the id of the last
    solid whose surface, the half-coverage level of the density's edge, contains it; 0 outside all) and the
    names of the ids. Only ``ct-chest`` has them (:data:`CT_CHEST_LABELS`)."""
    if name != "ct-chest":
        raise IsplatError(f"sample {name!r}: --labels: only ct-chest has labelled solids")
    shape = tuple(int(x) for x in (shape or DEFAULT_SHAPES[name]))
    items = [(kind, c, h, axis, float(n + 1)) for n, (kind, c, h, axis, _) in enumerate(_ct_chest_items())]
    ni, nj, nk = shape
    vol = np.zeros((nk, nj, ni), dtype=np.float32)
    _paint(vol, *_prims(shape, items), 1e-6)        # an edge of no width: ids are not blended
    return np.rint(vol).astype(np.uint8), {n + 1: name for n, name in enumerate(CT_CHEST_LABELS)}


def make_sample(name: str, shape=None, seed: int = 0, dtype: str | None = None, background: float = 0.0):
    """Return ``(array[k, j, i], spacing_ijk)`` for sample ``name``; ``shape`` is ``(n_i, n_j, n_k)``.

    ``dtype`` (``uint8`` or ``float32``) applies to ``sphere`` and ``two-density-cube`` only; ``background``
    (a value offset with its noise, see ``_mr_head``) to ``mr-head`` only.
    """
    if name not in DEFAULT_SHAPES:
        raise IsplatError(f"sample {name!r}: unknown; expected one of {', '.join(NAMES)}")
    shape = tuple(int(x) for x in (shape or DEFAULT_SHAPES[name]))
    if len(shape) != 3 or min(shape) < 2:
        raise IsplatError(f"sample {name!r}: shape {shape} invalid; expected three sizes >= 2 (NI,NJ,NK)")
    if int(np.prod(shape, dtype=np.int64)) > 2**31:
        raise IsplatError(f"sample {name!r}: shape {shape} has more than 2^31 voxels")
    if dtype is not None:
        if name not in ("sphere", "two-density-cube"):
            raise IsplatError(f"sample {name!r}: --dtype applies to sphere and two-density-cube only")
        if dtype not in ("uint8", "float32"):
            raise IsplatError(f"sample {name!r}: dtype {dtype!r} invalid; expected uint8 or float32")
    if name == "head":
        return _head(shape, seed)
    if name == "engine":
        return _engine(shape, seed)
    if name == "marschner-lobb":
        return _marschner_lobb(shape)
    if background:
        if name != "mr-head":
            raise IsplatError(f"sample {name!r}: --background applies to mr-head only")
        if not (0 < background <= 20000):
            raise IsplatError(f"sample {name!r}: background {background:g} invalid; expected a value in (0, 20000]")
        return _mr_head(shape, seed, float(background))
    if name in ("ct-head", "ct-chest", "mr-head"):
        return {"ct-head": _ct_head, "ct-chest": _ct_chest, "mr-head": _mr_head}[name](shape, seed)
    if name == "sphere":
        return _sphere(shape, dtype or "float32"), (1.0, 1.0, 1.0)
    return _two_density_cube(shape, dtype or "uint8"), (1.0, 1.0, 1.0)
