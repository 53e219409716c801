"""tests/paired_times.py: the paired sign test that decides "faster" on docs/accuracy.md's Pareto fronts."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from paired_times import ALPHA, MARGIN, compare, dominates, faster, front, min_wins, not_slower, sign_test_p

ROUNDS = 25      # benchmarks/accuracy.py's rounds per setting


def load(rng, rounds=ROUNDS):
    """One load factor per round, shared by the settings of the round (what interleaving cancels)."""
    return rng.uniform(0.8, 1.6, rounds)


def noisy(rng, base, shared, cv=0.15, bursts=0.2):
    """Per-round times of a setting taking ``base``: the round's ``shared`` load, independent jitter of ``cv``
    per frame, and a share ``bursts`` of frames hit by a 1.5-3x burst of load."""
    n = len(shared)
    t = base * shared * rng.lognormal(0.0, cv, n)
    return t * np.where(rng.random(n) < bursts, rng.uniform(1.5, 3.0, n), 1.0)


def test_sign_test_p_matches_binomial_sum():
    for n in range(0, 30):
        for w in range(0, n + 1):
            direct = sum(math.comb(n, k) for k in range(w, n + 1)) / 2 ** n
            assert sign_test_p(w, n) == pytest.approx(direct, rel=1e-12)
    with pytest.raises(ValueError):
        sign_test_p(5, 4)


def test_a_real_difference_is_called():
    """Stride 2 against stride 1 (about 0.6x the time) and a 15% difference are called under noise (shared load
    per round, 5% jitter per frame, a tenth of the frames of each hit by a burst) with the benchmark's rounds; the
    slower one is never called faster."""
    rng = np.random.default_rng(1)
    for ratio, least in ((0.6, 0.95), (0.85, 0.85)):
        called = 0
        for _ in range(100):
            shared = load(rng)
            a, b = (noisy(rng, base, shared, cv=0.05, bursts=0.1) for base in (10.0 * ratio, 10.0))
            called += faster(a, b)
            assert not faster(b, a)
        assert called >= least * 100, (ratio, called)


def test_noise_only_is_not_called():
    """Equal work (same base time, noise of every kind): called faster in well under alpha of the draws."""
    rng = np.random.default_rng(2)
    calls = 0
    trials = 2000
    for _ in range(trials):
        shared = load(rng)
        a, b = noisy(rng, 10.0, shared), noisy(rng, 10.0, shared)
        calls += faster(a, b)
    assert calls <= ALPHA * trials, calls


def test_consistent_but_small_difference_is_a_tie():
    """A 1% difference in every round is significant but below the margin: not called."""
    b = np.linspace(5.0, 9.0, ROUNDS)
    assert compare(0.99 * b, b).p < ALPHA
    assert not faster(0.99 * b, b)
    assert faster((1 - 2 * MARGIN) * b, b)


def test_one_huge_outlier_does_not_decide():
    """A's frames are slower in every round but one, where B's frame took 100x: B is still not slower."""
    b = np.full(ROUNDS, 10.0)
    a = np.full(ROUNDS, 11.0)
    b[3] = 1000.0
    assert not faster(a, b)
    assert faster(b, a)


def test_not_slower_needs_evidence():
    """A 25% slower setting under noise is shown "not slower" in at most alpha of the draws; the same work with
    1% jitter is shown not slower in most; 2% slower without noise is within the margin, 4% is not."""
    rng = np.random.default_rng(4)
    wrong = right = 0
    for _ in range(1000):
        shared = load(rng)
        wrong += not_slower(noisy(rng, 12.5, shared), noisy(rng, 10.0, shared))
        right += not_slower(noisy(rng, 10.0, shared, cv=0.01, bursts=0.0), noisy(rng, 10.0, shared, cv=0.01,
                                                                                   bursts=0.0))
    assert wrong <= ALPHA * 1000, wrong
    assert right >= 900, right
    b = np.linspace(5.0, 9.0, ROUNDS)
    assert not_slower(1.02 * b, b) and not not_slower(1.04 * b, b)


def test_too_few_rounds_never_call():
    assert min_wins(6) is None and min_wins(7) == 7
    assert not faster([1.0] * 6, [10.0] * 6) and not not_slower([1.0] * 6, [10.0] * 6)
    assert faster([1.0] * 7, [10.0] * 7) and not_slower([1.0] * 7, [10.0] * 7)


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        compare([1.0, 2.0], [1.0])
    with pytest.raises(ValueError):
        compare([], [])
    with pytest.raises(ValueError):
        compare([1.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError):
        compare([1.0, float("nan")], [1.0, 1.0])
    with pytest.raises(ValueError):
        dominates([1.0], 0.1, [1.0], 0.1, tol=-1.0)
    with pytest.raises(ValueError):
        front([[1.0]], [0.1, 0.2])


def test_front_keeps_ties_and_drops_beaten():
    rng = np.random.default_rng(3)
    base = noisy(rng, 10.0, load(rng))
    same = base * rng.lognormal(0.0, 0.02, ROUNDS)      # the same work, another knob (e.g. precision)
    half = 0.5 * base                                    # half the work
    slow = 2.0 * base
    times = [base, same, half, slow]
    errors = [0.010, 0.010, 0.030, 0.010]
    assert front(times, errors, tol=1e-4)[0] == 2       # fastest first
    assert set(front(times, errors, tol=1e-4)) == {0, 1, 2}   # ties in both stay; slower, equally close goes
    assert front(times, [0.010, 0.005, 0.030, 0.010], tol=1e-4) == [2, 1]   # closer at the same time wins


@st.composite
def two_points(draw):
    n = draw(st.integers(1, 25))
    t = st.lists(st.floats(0.1, 100.0), min_size=n, max_size=n)
    e = st.floats(0.0, 1.0)
    return draw(t), draw(e), draw(t), draw(e), draw(st.floats(0.0, 0.1)), draw(st.floats(0.0, 0.2))


@settings(max_examples=300, deadline=None)
@given(two_points())
def test_relations_are_irreflexive_and_antisymmetric(pts):
    ta, ea, tb, eb, tol, margin = pts
    assert not faster(ta, ta, margin)
    if margin > 0:      # every round of A against itself is within the margin: shown when the rounds can show it
        assert not_slower(ta, ta, margin) == (min_wins(len(ta)) is not None)
    assert not dominates(ta, ea, ta, ea, tol, margin)
    assert not (faster(ta, tb, margin) and faster(tb, ta, margin))
    assert not (dominates(ta, ea, tb, eb, tol, margin) and dominates(tb, eb, ta, ea, tol, margin))
    # the ratio of A to B is the reciprocal of B's to A, and the wins add up to the differing rounds
    ab, ba = compare(ta, tb, margin), compare(tb, ta, margin)
    assert ab.ratio * ba.ratio == pytest.approx(1.0, rel=1e-9)
    assert ab.wins + ba.wins == ab.n == ba.n


def classic_front(scales, errors, tol, margin):
    """The front of scalar times, written out: B is beaten when some A is as close within tol, and faster by more
    than the margin, or closer by more than tol and slower by at most the margin."""
    def fast(x, y):
        return x < (1 - margin) * y
    return {i for i in range(len(scales))
            if not any(errors[j] <= errors[i] + tol and (fast(scales[j], scales[i]) or (
                       errors[j] < errors[i] - tol and scales[j] < (1 + margin) * scales[i]))
                       for j in range(len(scales)) if j != i)}


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.5, 2.0), st.floats(0.0, 1.0)), min_size=1, max_size=8),
       st.floats(0.0, 0.05), st.integers(0, 2 ** 32 - 1))
def test_front_without_noise_is_the_classic_front(points, tol, seed):
    """When every round scales the same load by a setting's constant, the sign test is unanimous and the front
    is the scalar one with the margin as the time tolerance."""
    shared = load(np.random.default_rng(seed))
    times = [s * shared for s, _ in points]
    scales, errors = [s for s, _ in points], [e for _, e in points]
    on = front(times, errors, tol)
    assert set(on) == classic_front(scales, errors, tol, MARGIN)
    assert all(scales[a] <= scales[b] * (1 + 1e-12) for a, b in zip(on, on[1:]))     # fastest first
