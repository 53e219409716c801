"""Octahedral 16-bit unit normals ("oct16", precise encoder; Cigolle et al. 2014, JCGT 3(2)).

A unit vector ``n = (n_i, n_j, n_k)`` is projected onto the octahedron ``|x|+|y|+|z| = 1``; the lower half
(``n_k < 0``) is folded over the diagonals onto the square ``[-1, 1]^2``. The two square coordinates are
stored as snorm8 bytes ``u`` (high byte, from ``n_i``) and ``v`` (low byte, from ``n_j``): a byte ``c`` in
``-127..127`` means ``c / 127``. ``code = (u_byte << 8) | v_byte`` with two's-complement bytes.

The precise encoder tries the four floor/ceil roundings of ``(u, v)`` and keeps the one whose decoded
vector is closest in angle to the input (max error about 0.64 degrees instead of 0.9 for plain rounding).

``NO_NORMAL = 0x8080`` (both bytes -128, never produced for a non-zero vector) marks a zero gradient and
decodes to ``(0, 0, 0)``, so flat regions never produce NaN. Other codes with a -128 byte decode as if the
byte were -127 (snorm8 clamping). The octahedral fold uses ``sign(0) := +1``.

This is the paper's "two bytes for encoded normal" (§2.1, §4); the byte layout is in formats/augmented.md.
"""

from __future__ import annotations

import functools

import numpy as np

from .jit import jit, stage

NO_NORMAL = 0x8080


@stage(forceinline=True)
def _sgn(x):
    return 1.0 if x >= 0.0 else -1.0


@stage(forceinline=True)
def _decode_uv(cu, cv):
    """Unnormalised direction of the snorm8 pair (cu, cv) in -127..127."""
    x = cu / 127.0
    y = cv / 127.0
    z = 1.0 - abs(x) - abs(y)
    if z < 0.0:
        x, y = (1.0 - abs(y)) * _sgn(x), (1.0 - abs(x)) * _sgn(y)
    return x, y, z


@stage
def _encode_one(x, y, z):
    n1 = abs(x) + abs(y) + abs(z)
    if not (n1 > 0.0) or not np.isfinite(n1):
        return NO_NORMAL
    px = x / n1
    py = y / n1
    if z < 0.0:
        px, py = (1.0 - abs(py)) * _sgn(px), (1.0 - abs(px)) * _sgn(py)
    fu = np.floor(min(max(px, -1.0), 1.0) * 127.0)
    fv = np.floor(min(max(py, -1.0), 1.0) * 127.0)
    # unit input for the angle comparison (cosine of the angle = dot / |decoded|)
    n2 = np.sqrt(x * x + y * y + z * z)
    ux, uy, uz = x / n2, y / n2, z / n2
    best_cos = -2.0
    best_u = 0
    best_v = 0
    for du in range(2):
        for dv in range(2):
            cu = min(max(fu + du, -127.0), 127.0)
            cv = min(max(fv + dv, -127.0), 127.0)
            dx, dy, dz = _decode_uv(cu, cv)
            c = (dx * ux + dy * uy + dz * uz) / np.sqrt(dx * dx + dy * dy + dz * dz)
            if c > best_cos:  # strict: ties keep the first candidate in (du, dv) order
                best_cos = c
                best_u = int(cu)
                best_v = int(cv)
    return ((best_u & 0xFF) << 8) | (best_v & 0xFF)


@jit
def _encode_flat(v, out):
    for n in range(out.shape[0]):
        out[n] = _encode_one(np.float64(v[n, 0]), np.float64(v[n, 1]), np.float64(v[n, 2]))


def encode(vectors) -> np.ndarray:
    """Encode vectors ``float[..., 3]`` (any length; zero or non-finite -> NO_NORMAL) as uint16 codes."""
    v = np.asarray(vectors)
    if v.shape[-1:] != (3,):
        raise ValueError(f"encode expects an array of shape (..., 3), got {v.shape}")
    if not np.issubdtype(v.dtype, np.floating):
        v = v.astype(np.float64)
    flat = np.ascontiguousarray(v.reshape(-1, 3))
    out = np.empty(flat.shape[0], dtype=np.uint16)
    _encode_flat(flat, out)
    return out.reshape(v.shape[:-1])


@functools.lru_cache(maxsize=1)
def _lut() -> np.ndarray:
    codes = np.arange(65536, dtype=np.uint32)
    cu = ((codes >> 8).astype(np.uint8).view(np.int8)).astype(np.float64)
    cv = ((codes & 0xFF).astype(np.uint8).view(np.int8)).astype(np.float64)
    x = np.maximum(cu, -127.0) / 127.0
    y = np.maximum(cv, -127.0) / 127.0
    z = 1.0 - np.abs(x) - np.abs(y)
    fold = z < 0
    sx = np.where(x >= 0, 1.0, -1.0)
    sy = np.where(y >= 0, 1.0, -1.0)
    x2 = np.where(fold, (1.0 - np.abs(y)) * sx, x)
    y2 = np.where(fold, (1.0 - np.abs(x)) * sy, y)
    d = np.stack([x2, y2, z], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d[NO_NORMAL] = 0.0
    lut = d.astype(np.float32)
    lut.flags.writeable = False
    return lut


def decode_lut() -> np.ndarray:
    """Return the read-only table ``float32[65536, 3]`` of decoded unit normals (row NO_NORMAL is zero)."""
    return _lut()


def decode(codes) -> np.ndarray:
    """Decode uint16 codes ``[...]`` to unit vectors ``float32[..., 3]`` (NO_NORMAL -> (0, 0, 0))."""
    c = np.asarray(codes)
    if not (np.issubdtype(c.dtype, np.integer) and (c.size == 0 or (c.min() >= 0 and c.max() <= 0xFFFF))):
        raise ValueError("decode expects integer codes in 0..65535")
    return _lut()[c.astype(np.uint16)]
