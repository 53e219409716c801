"""tests/ceiling_rounds.py: the per-round ceiling statistics of docs/worksplit.md (issue 27 item 5)."""

import math
import statistics

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ceiling_rounds import FLOOR, ceiling

times = st.floats(min_value=1e-3, max_value=10.0, allow_nan=False, allow_infinity=False)
rounds = st.integers(min_value=1, max_value=40).flatmap(
    lambda n: st.tuples(*(st.lists(times, min_size=n, max_size=n) for _ in range(3))))


def reference(one, two, pair, floor):
    """The obvious way: one round at a time, the standard library's median and quartiles."""
    speedup = [o / t for o, t in zip(one, two)]
    gain = [2 * o / p for o, p in zip(one, pair)]
    of = [s / g for s, g in zip(speedup, gain)]
    full = [i for i, g in enumerate(gain) if g >= floor]

    def quartiles(x):
        if len(x) == 1:
            return x[0], x[0]
        q = statistics.quantiles(x, n=4, method="inclusive")
        return q[0], q[2]
    return dict(rounds=len(one), speedup=statistics.median(speedup), gain=statistics.median(gain),
                of=statistics.median(of), of_quartiles=quartiles(of), of_range=(min(of), max(of)),
                two_cores=len(full),
                speedup_two_cores=statistics.median([speedup[i] for i in full]) if full else None,
                speedup_two_cores_quartiles=quartiles([speedup[i] for i in full]) if full else None,
                of_two_cores=statistics.median([of[i] for i in full]) if full else None)


def close(a, b):
    if a is None or b is None:
        return a is b
    if isinstance(a, tuple):
        return len(a) == len(b) and all(close(x, y) for x, y in zip(a, b))
    return math.isclose(a, b, rel_tol=1e-9)


@settings(max_examples=300, deadline=None)
@given(rounds, st.sampled_from([1.0, FLOOR, 2.0]))
def test_matches_reference(r, floor):
    one, two, pair = r
    got = ceiling(one, two, pair, floor)
    want = reference(one, two, pair, floor)
    for key, value in want.items():
        assert close(getattr(got, key), value), (key, getattr(got, key), value)
    assert got.share_two_cores == want["two_cores"] / want["rounds"]


@settings(max_examples=200, deadline=None)
@given(rounds, st.data())
def test_a_rounds_load_cancels(r, data):
    """A load that slows a round's three measurements alike changes nothing: each round is its own reference."""
    one, two, pair = map(np.asarray, r)
    f = np.asarray(data.draw(st.lists(st.floats(0.25, 4.0), min_size=len(one), max_size=len(one))))
    a, b = ceiling(one, two, pair), ceiling(one * f, two * f, pair * f)
    for key in ("speedup", "gain", "of", "of_quartiles", "of_range", "speedup_two_cores", "of_two_cores"):
        x, y = getattr(a, key), getattr(b, key)
        assert (x is None and y is None) or np.allclose(x, y, rtol=1e-9), key
    # the floor is compared with each round's gain, which f cancels in, up to rounding at the boundary
    assert abs(a.two_cores - b.two_cores) <= np.count_nonzero(np.isclose(2 * one / pair, FLOOR, rtol=1e-12))


def test_the_speed_up_is_compared_with_its_own_rounds_ceiling():
    """Loaded rounds (gain 1) and free ones (gain 2) alternate, and isplat gets 0.95 of the gain in every round:
    of that is 0.95 exactly, and the speed-up where the machine gave two cores is 1.9, not the loaded rounds'."""
    one = np.array([10.0, 20.0] * 6)
    gain = np.array([2.0, 1.0] * 6)
    pair, two = 2 * one / gain, one / (0.95 * gain)
    c = ceiling(one, two, pair)
    assert c.of == pytest.approx(0.95) and c.of_range == pytest.approx((0.95, 0.95))
    assert c.two_cores == 6 and c.share_two_cores == 0.5
    assert c.speedup_two_cores == pytest.approx(1.9) and c.of_two_cores == pytest.approx(0.95)


def test_floor_is_inclusive_and_no_round_reaching_it_gives_none():
    c = ceiling([1.85, 1.0], [1.0, 1.0], [2.0, 2.0])       # gains 1.85 (exactly) and 1.0
    assert c.two_cores == 1 and c.speedup_two_cores == 1.85
    c = ceiling([1.0, 1.0], [1.0, 1.0], [2.0, 1.5])         # gains 1.0 and 1.33
    assert c.two_cores == 0 and c.speedup_two_cores is None and c.of_two_cores is None
    assert c.speedup_two_cores_quartiles is None


@pytest.mark.parametrize("one, two, pair, floor", [
    ([], [], [], FLOOR),
    ([1.0, 1.0], [1.0], [1.0, 1.0], FLOOR),
    ([[1.0]], [[1.0]], [[1.0]], FLOOR),
    ([1.0], [0.0], [1.0], FLOOR),
    ([1.0], [1.0], [-1.0], FLOOR),
    ([math.nan], [1.0], [1.0], FLOOR),
    ([1.0], [math.inf], [1.0], FLOOR),
    ([1.0], [1.0], [1.0], 0.0),
    ([1.0], [1.0], [1.0], math.nan),
])
def test_bad_input_is_refused(one, two, pair, floor):
    with pytest.raises(ValueError):
        ceiling(one, two, pair, floor)
