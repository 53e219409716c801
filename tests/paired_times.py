"""Is one setting faster than another, from frame times measured in rounds: a paired test that allows for noise.

Shared by benchmarks/accuracy.py (its Pareto fronts, docs/accuracy.md) and tests/test_paired_times.py, the way
tests/ray_reference.py and tests/fuzzlab.py are: it lives in tests/ so that the tests need not import
``benchmarks``, and it is no part of the installed library.

The benchmark renders every setting once per round, in a fresh random order each round, so that a burst of load
from other processes on this shared machine hits the settings of one round alike. Settings A and B are compared
round by round: the ratio of A's frame time to B's in the same round. **A is faster than B** when both hold:

- the median per-round ratio (the exponential of the median of the log ratios, so that A/B and B/A are
  reciprocal) is below ``1 - margin``: a difference smaller than the margin is not worth calling;
- a one-sided sign test over the rounds rejects "A's frame is as likely slower as faster" at level ``alpha``:
  the number of rounds where A's frame was faster is so large that a fair coin would give as many with
  probability below ``alpha`` (rounds with equal times are left out). The sign test assumes nothing about the
  noise's distribution and ignores the size of outliers, so one slow frame from a burst of load counts as one
  lost round, not as a large time.

Otherwise neither is faster: a tie in time. **A is not slower than B** when the sign test shows that A's frame is
below ``1 + margin`` times B's in more rounds than chance would give (one-sided, level ``alpha``): evidence that A
is at most ``margin`` slower, not merely the absence of evidence that it is slower.

A point (times, error) **dominates** another when its error is at most the other's plus ``tol`` (errors within
``tol`` are equal) and either it is faster, or its error is smaller by more than ``tol`` and it is not slower.
Each claim needs its evidence, so that "the defaults are not on the front" is said only when the rounds show it:
a closer setting whose frames are too noisy to show it is not slower does not push another off the front. The
**front** is the points no other point dominates. Both relations are irreflexive and antisymmetric
(tests/test_paired_times.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MARGIN = 0.03      # a median per-round ratio within 3% of 1 is a tie, however consistent
ALPHA = 0.01       # one-sided level of the sign test, per pair (the front tests many pairs)


def sign_test_p(wins: int, n: int) -> float:
    """One-sided p-value of the sign test: P(X >= wins) for X ~ Binomial(n, 1/2).

    >>> sign_test_p(7, 7) == 0.5 ** 7
    True
    >>> round(sign_test_p(17, 21), 4)
    0.0036
    >>> sign_test_p(0, 0)
    1.0
    """
    if not 0 <= wins <= n:
        raise ValueError(f"wins must be in 0..n, got wins={wins}, n={n}")
    return math.fsum(math.comb(n, k) for k in range(wins, n + 1)) / 2.0 ** n


def min_wins(n: int, alpha: float = ALPHA) -> int | None:
    """The fewest rounds out of ``n`` that A must win for the sign test to call it at level ``alpha``, or None
    when no number can (too few rounds: ``0.5 ** n >= alpha``).

    >>> min_wins(21), min_wins(6), min_wins(7)
    (17, None, 7)
    """
    return next((w for w in range(n + 1) if sign_test_p(w, n) < alpha), None)


@dataclass(frozen=True)
class Comparison:
    """A's frame times against B's, round by round."""
    ratio: float        # median per-round ratio A/B (exp of the median log ratio)
    wins: int           # rounds where A's frame was faster
    n: int              # rounds where the two differ (the sign test's sample)
    p: float            # one-sided sign-test p-value that A is faster
    faster: bool        # A is faster than B by the rule above


def per_round(*series) -> list[np.ndarray]:
    """``series`` (one frame time per round each, the same rounds) as float64 arrays, checked: 1-d, of one
    non-zero length, finite and positive (also tests/ceiling_rounds.py's input)."""
    t = [np.asarray(a, dtype=np.float64) for a in series]
    if any(a.ndim != 1 or a.shape != t[0].shape for a in t) or t[0].size == 0:
        raise ValueError(f"need {len(t)} 1-d arrays of the same non-zero length (one time per round), got shapes "
                         f"{[a.shape for a in t]}")
    if not all(np.all(np.isfinite(a)) and np.all(a > 0) for a in t):
        raise ValueError("frame times must be finite and positive")
    return t


def compare(a, b, margin: float = MARGIN, alpha: float = ALPHA) -> Comparison:
    """A's per-round frame times ``a`` against B's ``b`` (same rounds, same order).

    >>> c = compare([1.0, 1.1, 0.9, 1.0, 1.0, 1.2, 0.95], [2.0, 2.1, 2.0, 1.9, 2.2, 2.0, 2.05])
    >>> round(c.ratio, 2), c.wins, c.n, c.faster
    (0.5, 7, 7, True)
    >>> compare([1.0, 1.0, 1.0], [2.0, 2.0, 2.0]).faster   # 3 rounds cannot show it at alpha = 0.01
    False
    """
    a, b = per_round(a, b)
    logs = np.log(a) - np.log(b)
    ratio = float(np.exp(np.median(logs)))
    wins, n = int(np.count_nonzero(logs < 0)), int(np.count_nonzero(logs != 0))
    p = sign_test_p(wins, n)
    return Comparison(ratio=ratio, wins=wins, n=n, p=p, faster=bool(ratio < 1.0 - margin and p < alpha))


def faster(a, b, margin: float = MARGIN, alpha: float = ALPHA) -> bool:
    """A (per-round times ``a``) is faster than B (``b``): see :func:`compare`."""
    return compare(a, b, margin, alpha).faster


def not_slower(a, b, margin: float = MARGIN, alpha: float = ALPHA) -> bool:
    """A's frame is below ``1 + margin`` times B's in so many rounds that the one-sided sign test rejects "A is
    slower by more than the margin" at level ``alpha``.

    >>> not_slower([1.0] * 9, [1.0] * 9), not_slower([1.0] * 9, [0.9] * 9)
    (True, False)
    >>> not_slower([1.02] * 9, [1.0] * 9), not_slower([1.0, 1.0, 1.0], [1.0, 1.0, 1.0])
    (True, False)
    """
    a, b = per_round(a, b)
    logs = np.log(a) - np.log(b) - math.log1p(margin)
    return sign_test_p(int(np.count_nonzero(logs < 0)), int(np.count_nonzero(logs != 0))) < alpha


def dominates(ta, ea: float, tb, eb: float, tol: float = 0.0, margin: float = MARGIN,
              alpha: float = ALPHA) -> bool:
    """Point A (per-round times ``ta``, error ``ea``) dominates point B: as close within ``tol``, and faster, or
    closer by more than ``tol`` and not slower.

    >>> dominates([1.0] * 9, 0.5, [2.0] * 9, 0.5)
    True
    >>> dominates([1.0] * 9, 0.5, [2.0] * 9, 0.4)          # faster but farther
    False
    >>> dominates([1.0] * 9, 0.5, [1.0] * 9, 0.6)          # as fast, closer
    True
    >>> dominates([1.0] * 3, 0.5, [1.0] * 3, 0.6)          # closer, but 3 rounds cannot show "not slower"
    False
    """
    if tol < 0 or not (math.isfinite(ea) and math.isfinite(eb)):
        raise ValueError(f"need finite errors and tol >= 0, got {ea}, {eb}, tol={tol}")
    if ea > eb + tol:
        return False
    if faster(ta, tb, margin, alpha):
        return True
    return ea < eb - tol and not_slower(ta, tb, margin, alpha)


def front(times, errors, tol: float = 0.0, margin: float = MARGIN, alpha: float = ALPHA) -> list[int]:
    """Indices of the points (``times[i]``: per-round frame times, ``errors[i]``) that no other point dominates,
    fastest (smallest median time) first.

    >>> front([[1.0] * 9, [2.0] * 9, [3.0] * 9, [2.0] * 9], [3.0, 2.0, 3.0, 1.0])
    [0, 3]
    """
    if len(times) != len(errors):
        raise ValueError(f"{len(times)} time series but {len(errors)} errors")
    on = [i for i in range(len(times))
          if not any(dominates(times[j], errors[j], times[i], errors[i], tol, margin, alpha)
                     for j in range(len(times)) if j != i)]
    return sorted(on, key=lambda i: float(np.median(times[i])))
