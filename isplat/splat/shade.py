"""Shading: Phong terms for the 65,536 normal codes, one compiled pass per view.

Lights are given in camera space, normals in the volume's i, j, k axes; :func:`shade_table` turns the lights
into volume axes once per frame and tabulates every code, so a voxel's shading is one table look-up. The last
few tables are kept, so frames of the same view (another transfer function, another image size) reuse theirs.
"""

from __future__ import annotations

import functools

import numpy as np

from ..jit import jit
from ..threads import run_parallel


def shade_table(shading, frame, geom, dtype=np.float32, threads: int = 1) -> np.ndarray:
    """Per normal code: (diffuse r, g, b, specular r, g, b) for this view's lights (Phong, infinite viewer),
    or just (diffuse, specular) when every light is white; the codes are shared out between ``threads``.

    The table is shared with later calls for the same lights, view direction, Phong terms and threads (one of
    the last four, :func:`_table`): do not write to it. (It stays writeable, as the kernels were compiled
    for.)"""
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
    args = (float(shading.ambient), float(shading.diffuse), float(shading.specular), float(shading.shininess),
            bool(shading.two_sided))
    return _table(lights.tobytes(), args, np.dtype(dtype).str, threads)


@functools.lru_cache(maxsize=4)         # 1.5 MB each at most
def _table(lights_bytes: bytes, args: tuple, dtype: str, threads: int) -> np.ndarray:
    """:func:`shade_table`'s table for ``lights`` rows (L, H, rgb) given as bytes, so that they can be a key."""
    from ..normals import decode_lut

    lights = np.frombuffer(lights_bytes, dtype=np.float64).reshape(-1, 9).copy()   # writeable, as compiled for
    # white lights: r, g and b factors are equal, one diffuse and one specular factor per code will do
    white = bool(np.all(lights[:, 6:9] == lights[:, 6:7]))
    out = np.empty((65536, 2 if white else 6), dtype=dtype)
    normals = decode_lut()
    # the codes are independent: share them out between the threads (the kernel releases the GIL)
    cuts = np.linspace(0, normals.shape[0], max(1, threads) + 1).astype(int)
    parts = [(normals[a:b], out[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]
    run_parallel(lambda p: shade_codes(p[0], lights, *args, p[1]), parts, threads)
    return out


@jit
def shade_codes(normals, lights, ambient, diffuse, specular, shininess, two_sided, out):
    """Phong terms per normal code: ``out[c] = (diffuse r, g, b, specular r, g, b)``, or, when ``out`` has two
    columns (every light white), ``(diffuse, specular)``.

    ``lights`` rows: (L_i, L_j, L_k, H_i, H_j, H_k, r, g, b) in volume axes, L towards the light, H the
    half vector with the viewer, rgb the light's colour times intensity (r for a white light).
    """
    mono = out.shape[1] == 2
    whole = np.int64(shininess)             # a whole exponent: multiplications, not pow (3x faster per code)
    if whole != shininess:
        whole = -1
    for c in range(normals.shape[0]):
        nx = normals[c, 0]
        ny = normals[c, 1]
        nz = normals[c, 2]
        dr = ambient
        dg = ambient
        db = ambient
        sr = 0.0
        sg = 0.0
        sb = 0.0
        for li in range(lights.shape[0]):
            ndl = nx * lights[li, 0] + ny * lights[li, 1] + nz * lights[li, 2]
            ndh = nx * lights[li, 3] + ny * lights[li, 4] + nz * lights[li, 5]
            if two_sided:
                ndl = abs(ndl)
                ndh = abs(ndh)
            else:
                if ndl <= 0.0:
                    ndl = 0.0
                    ndh = 0.0
                ndh = max(ndh, 0.0)
            sp = 0.0
            if ndh > 0.0 and specular != 0.0:
                sp = specular * (ndh ** whole if whole >= 0 else ndh ** shininess)
            dr += diffuse * ndl * lights[li, 6]
            sr += sp * lights[li, 6]
            if not mono:
                dg += diffuse * ndl * lights[li, 7]
                db += diffuse * ndl * lights[li, 8]
                sg += sp * lights[li, 7]
                sb += sp * lights[li, 8]
        out[c, 0] = dr
        if mono:
            out[c, 1] = sr
        else:
            out[c, 1] = dg
            out[c, 2] = db
            out[c, 3] = sr
            out[c, 4] = sg
            out[c, 5] = sb
