"""Octahedral 16-bit normals: round trip error, idempotence, reserved code, and a pure-Python reference."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from isplat import normals as N


def _sgn(x):
    return 1.0 if x >= 0 else -1.0


def ref_decode(code):
    """Obvious decoder straight from formats/augmented.md §5."""
    if code == N.NO_NORMAL:
        return (0.0, 0.0, 0.0)
    u = (code >> 8) & 0xFF
    v = code & 0xFF
    u = u - 256 if u > 127 else u
    v = v - 256 if v > 127 else v
    x, y = max(u, -127) / 127, max(v, -127) / 127
    z = 1 - abs(x) - abs(y)
    if z < 0:
        x, y = (1 - abs(y)) * _sgn(x), (1 - abs(x)) * _sgn(y)
    n = math.sqrt(x * x + y * y + z * z)
    return (x / n, y / n, z / n)


def ref_encode(v):
    """Obvious precise encoder: try the four floor/ceil codes, keep the smallest angle (first on ties)."""
    x, y, z = (float(c) for c in v)
    s = abs(x) + abs(y) + abs(z)
    if s == 0:
        return N.NO_NORMAL
    px, py = x / s, y / s
    if z < 0:
        px, py = (1 - abs(py)) * _sgn(px), (1 - abs(px)) * _sgn(py)
    n = math.sqrt(x * x + y * y + z * z)
    best = None
    for a in (0, 1):
        for b in (0, 1):
            cu = int(min(max(math.floor(px * 127) + a, -127), 127))
            cv = int(min(max(math.floor(py * 127) + b, -127), 127))
            code = ((cu & 0xFF) << 8) | (cv & 0xFF)
            d = ref_decode(code)
            cos = (d[0] * x + d[1] * y + d[2] * z) / n
            if best is None or cos > best[0]:
                best = (cos, code)
    return best[1]


def _angle_deg(a, b):
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    c = (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


unit = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(lambda v: sum(c * c for c in v) > 1e-6)


@settings(max_examples=500, deadline=None)
@given(unit)
def test_round_trip_error_below_0_65_degrees(v):
    v = np.asarray(v, np.float64)
    assert _angle_deg(N.decode(N.encode(v)), v) < 0.65


def test_round_trip_many_random_vectors():
    rng = np.random.default_rng(1)
    v = rng.standard_normal((200_000, 3))
    err = _angle_deg(N.decode(N.encode(v)), v)
    assert err.max() < 0.65
    assert 0.2 < err.mean() < 0.4


def test_encode_decode_idempotent_on_all_codes():
    codes = np.arange(65536, dtype=np.uint16)
    f1 = N.encode(N.decode(codes))
    f2 = N.encode(N.decode(f1))
    assert np.array_equal(f1, f2)
    # every code a conforming encoder writes is a fixed point
    assert np.array_equal(N.encode(N.decode(f1)), f1)


def test_no_normal():
    assert N.NO_NORMAL == 0x8080
    assert N.encode(np.zeros(3)) == N.NO_NORMAL
    assert np.array_equal(N.decode(N.NO_NORMAL), [0, 0, 0])
    assert N.encode(N.decode(N.NO_NORMAL)) == N.NO_NORMAL
    # non-finite input is no normal either, never NaN out
    assert N.encode(np.array([np.nan, 0, 1])) == N.NO_NORMAL
    assert not np.isnan(N.decode_lut()).any()


def test_encoder_never_writes_minus_128():
    rng = np.random.default_rng(2)
    c = N.encode(rng.standard_normal((100_000, 3)))
    assert not np.any((c >> 8) == 0x80)
    assert not np.any((c & 0xFF) == 0x80)


def test_minus_128_bytes_decode_clamped():
    # u = -128, v = 0 decodes as u = -127
    assert np.allclose(N.decode(0x8000), N.decode(((-127 & 0xFF) << 8) | 0))
    assert np.allclose(N.decode(0x0080), N.decode(0x0081))


def test_axes_and_bit_layout():
    assert N.encode([1.0, 0, 0]) == (127 << 8)             # u = +127 high byte
    assert N.encode([0, 1.0, 0]) == 127                    # v = +127 low byte
    assert N.encode([0, 0, 1.0]) == 0
    assert np.allclose(N.decode(N.encode([0, 0, -1.0])), [0, 0, -1], atol=1e-6)
    assert np.allclose(N.decode(0x552A), [0.896527, 0.442990, 0], atol=1e-6)   # formats/augmented.md example
    assert int(N.encode(np.array([0.3, -0.2, -0.9]))) == 0x6D9C


def test_compiled_encoder_matches_reference():
    rng = np.random.default_rng(3)
    v = rng.standard_normal((3000, 3))
    v[:50, 2] = 0.0          # equator: fold boundary
    v[50:100, :2] = 0.0      # poles
    v[100:150, 0] = 0.0      # sign(0) on the fold
    v[150:200] = np.round(v[150:200], 1)
    got = N.encode(v)
    want = np.array([ref_encode(x) for x in v], dtype=np.uint16)
    assert np.array_equal(got, want)


def test_decode_lut_matches_reference():
    lut = N.decode_lut()
    assert lut.shape == (65536, 3) and lut.dtype == np.float32
    assert not lut.flags.writeable
    assert N.decode_lut() is lut
    for c in list(range(0, 65536, 97)) + [0x8080, 0x8000, 0x0080, 0x7F7F, 0x8181]:
        assert np.allclose(lut[c], ref_decode(c), atol=1e-6), c


def test_shapes_and_errors():
    v = np.ones((2, 3, 4, 3), np.float32)
    assert N.encode(v).shape == (2, 3, 4)
    assert N.decode(N.encode(v)).shape == (2, 3, 4, 3)
    with pytest.raises(ValueError):
        N.encode(np.ones((4, 2)))
    with pytest.raises(ValueError):
        N.decode(np.array([70000]))
