"""How much of the machine's own ceiling two threads reach, from frame times measured in rounds.

Shared by benchmarks/worksplit.py (docs/worksplit.md, issue 27 item 5) and tests/test_ceiling_rounds.py, the way
tests/paired_times.py is: it lives in tests/ so that the tests need not import ``benchmarks``, and it is no part of
the installed library.

Each round times, back to back, a one-thread frame (``one``), a two-thread frame (``two``) and *two copies*: two
one-thread frames of the same view at once, each in a renderer of its own (``pair``: the wall time of both). In
that round the 2-thread **speed-up** is ``one / two``, the machine's **gain** from two cores (its own ceiling:
two programs that share nothing) is ``2 one / pair``, and **of that** is speed-up / gain (``pair / (2 two)``).
On a shared machine the gain swings from round to round (another job takes a core, the host's load), so the
speed-up is only compared with the gain of its own round, and the statistics are over rounds: medians of the
per-round figures, never ratios of medians taken at different moments. A round whose gain is below ``floor``
had less than two cores: it says nothing about a speed-up of ``floor``, so the speed-up is also given over the
rounds with gain at least ``floor`` alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from paired_times import per_round      # the same per-round input check (both live in tests/, on sys.path)

FLOOR = 1.85     # issue 27 item 5: 2 threads at least 1.85x one thread


@dataclass(frozen=True)
class Ceiling:
    """Per-round statistics of :func:`ceiling`; quartiles are (25th, 75th) percentiles (numpy's linear)."""
    rounds: int
    speedup: float                  # median per-round 2-thread speed-up
    gain: float                     # median per-round two-copies gain
    of: float                       # median per-round speed-up / gain
    of_quartiles: tuple[float, float]
    of_range: tuple[float, float]
    floor: float
    two_cores: int                  # rounds with gain >= floor
    speedup_two_cores: float | None           # median speed-up over those rounds (None: no such round)
    speedup_two_cores_quartiles: tuple[float, float] | None
    of_two_cores: float | None      # median speed-up / gain over those rounds

    @property
    def share_two_cores(self) -> float:
        return self.two_cores / self.rounds


def _quartiles(x: np.ndarray) -> tuple[float, float]:
    return float(np.percentile(x, 25)), float(np.percentile(x, 75))


def ceiling(one, two, pair, floor: float = FLOOR) -> Ceiling:
    """The statistics of rounds ``one[i]``, ``two[i]``, ``pair[i]`` (wall seconds of the round's one-thread
    frame, two-thread frame and two copies at once).

    >>> c = ceiling([10.0, 10.0, 20.0], [5.5, 5.0, 12.0], [10.0, 12.5, 20.0])   # gains 2.0, 1.6, 2.0
    >>> round(c.speedup, 3), c.gain, round(c.of, 3), c.two_cores, round(c.speedup_two_cores, 3)
    (1.818, 2.0, 0.909, 2, 1.742)
    """
    one, two, pair = per_round(one, two, pair)
    if not (np.isfinite(floor) and floor > 0):
        raise ValueError(f"floor must be finite and positive, got {floor}")
    speedup, gain = one / two, 2.0 * one / pair
    of = speedup / gain
    full = gain >= floor
    med = lambda x: float(np.median(x))  # noqa: E731
    return Ceiling(rounds=int(one.size), speedup=med(speedup), gain=med(gain), of=med(of),
                   of_quartiles=_quartiles(of), of_range=(float(of.min()), float(of.max())), floor=float(floor),
                   two_cores=int(full.sum()),
                   speedup_two_cores=med(speedup[full]) if full.any() else None,
                   speedup_two_cores_quartiles=_quartiles(speedup[full]) if full.any() else None,
                   of_two_cores=med(of[full]) if full.any() else None)
