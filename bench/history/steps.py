"""Change points of one series: a penalised piecewise-constant fit, then the steps it finds tested.

Modelled on asv's step detection (airspeed-velocity/asv, `asv/step_detect.py`: `solve_potts`,
`detect_steps`, `detect_regressions`): the series is fitted by the piecewise-constant function
x minimising the Potts functional

    F[x] = gamma * (number of jumps of x) + sum_i w_i |y_i - x_i|

(L1 fit: each segment's level is the weighted median of its points), solved exactly by the
Bellman recursion of Friedrich et al. (2008), "Complexity penalized M-estimation", as
`solve_potts` does. Two departures from asv, both because gibench measures its noise:

* asv knows nothing of a point's noise and picks gamma per series with an information criterion
  (`solve_potts_autogamma`). Here every point carries its standard deviation sigma_i (timing:
  the spread of its frames and of the history's runs; errors: the reference noise floor and the
  metric's own interval), the weights are w_i = 1 / sigma_i, so the cost is in units of noise and
  one penalty `PENALTY` (calibrated on pure noise: tests/test_history.py) serves every series.
* asv's `detect_regressions` keeps an upward step when it exceeds the segments' L1 error and a
  relative threshold. Here a step must also be significant: its size over the standard error of
  the two levels (a median's: 1.2533 sigma / sqrt(n)) gives a one-sided p-value, adjusted over
  every step of the history by the gate's correction (bench.gate.statistics.adjust_p_values).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

# The jump penalty in units of noise-weighted L1 cost (sum of |y - level| / sigma). Measured on
# pure Gaussian noise of known sigma (tests/test_history.py): 4 fits a step into 7% of 30-point
# series, 6 into none of 300 (3..100 points); with sigma estimated from the series itself (as the
# history does) about 2-5% of series then show a step at p < 0.05, before the thresholds. The
# price: a single newest point is split off only when it lies more than 6 sigma from the level
# before it (a step with m points on each side needs about 6 / m sigma).
PENALTY = 6.0
MEDIAN_EFFICIENCY = 1.2533   # sd of a sample median / sd of the mean, Gaussian noise (sqrt(pi / 2))


@dataclass(frozen=True)
class Segment:
    """Points [start, stop) of a series at one level (the weighted median), with its standard error."""
    start: int
    stop: int
    level: float
    standard_error: float


@dataclass(frozen=True)
class Step:
    """A jump between two consecutive segments: the last point before it and the first after it."""
    before_index: int
    after_index: int
    level_before: float
    level_after: float
    standard_error: float     # of level_after - level_before
    p_up: float               # one-sided p-value that the level rose (unadjusted)
    p_down: float

    @property
    def size(self) -> float:
        return self.level_after - self.level_before

    def interval(self, z: float = 1.96) -> tuple[float, float]:
        return self.size - z * self.standard_error, self.size + z * self.standard_error


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The weighted median (asv's `weighted_median`: the mean of the two middle values at a tie)."""
    order = np.argsort(values, kind="stable")
    v, w = values[order], weights[order]
    cumulative = np.cumsum(w)
    half = cumulative[-1] / 2.0
    i = int(np.searchsorted(cumulative, half, side="left"))
    if math.isclose(cumulative[i], half, rel_tol=1e-12) and i + 1 < len(v):
        return float((v[i] + v[i + 1]) / 2.0)
    return float(v[i])


def segment_costs(values: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cost[l, r], level[l, r] of every segment l..r (inclusive): its weighted median (as
    `weighted_median`) and its weighted L1 distance to it. Per start l, every end at once: the
    values from l sorted once, and the prefix each end takes as a mask (O(n^3) arithmetic in numpy,
    milliseconds at n = 100)."""
    n = len(values)
    cost = np.full((n, n), np.inf)
    level = np.full((n, n), np.nan)
    for left in range(n):
        y, w = values[left:], weights[left:]
        m = len(y)
        order = np.argsort(y, kind="stable")
        ys, ws = y[order], w[order]
        ends = np.arange(1, m + 1)[:, None]
        included = order[None, :] < ends                  # [segment of length k + 1, sorted element j]
        cumulative = np.cumsum(np.where(included, ws[None, :], 0.0), axis=1)
        half = cumulative[:, -1] / 2.0
        first = np.argmax(cumulative >= half[:, None] * (1 - 1e-12), axis=1)
        rows = np.arange(m)
        tie = np.isclose(cumulative[rows, first], half, rtol=1e-12, atol=0.0)
        later = included & (np.arange(m)[None, :] > first[:, None])
        following = np.argmax(later, axis=1)
        medians = np.where(tie & later.any(axis=1), (ys[first] + ys[following]) / 2.0, ys[first])
        distances = np.where(np.arange(m)[None, :] < ends, w[None, :] * np.abs(y[None, :] - medians[:, None]), 0.0)
        level[left, left:] = medians
        cost[left, left:] = distances.sum(axis=1)
    return cost, level


def solve_potts(values, sigmas, penalty: float = PENALTY) -> list[Segment]:
    """The exact minimiser of the Potts functional (module docstring) as segments, oldest first.
    `sigmas` > 0: each point's standard deviation."""
    y = np.asarray(values, dtype=np.float64)
    sigma = np.asarray(sigmas, dtype=np.float64)
    if y.shape != sigma.shape or y.ndim != 1:
        raise ValueError("values and sigmas must be 1-D arrays of one length")
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(sigma)) and np.all(sigma > 0)):
        raise ValueError("values must be finite and sigmas finite and > 0")
    n = len(y)
    if n == 0:
        return []
    w = 1.0 / sigma
    cost, level = segment_costs(y, w)
    # best[r + 1]: the least F over points 0..r; start[r]: where the last segment of that optimum starts
    best = np.empty(n + 1)
    best[0] = -penalty
    start = np.zeros(n, dtype=int)
    for right in range(n):
        totals = best[:right + 1] + penalty + cost[:right + 1, right]
        left = int(np.argmin(totals))
        best[right + 1], start[right] = totals[left], left
    segments = []
    right = n - 1
    while right >= 0:
        left = int(start[right])
        se = MEDIAN_EFFICIENCY / math.sqrt(float(np.sum(w[left:right + 1] ** 2)))
        segments.append(Segment(left, right + 1, float(level[left, right]), se))
        right = left - 1
    return segments[::-1]


def one_sided_p(z: float) -> float:
    """P(Z > z) of a standard normal."""
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def detect_steps(values, sigmas, penalty: float = PENALTY) -> list[Step]:
    """The jumps of the Potts fit of a series, each with the standard error of its size and its
    one-sided p-values (unadjusted)."""
    return steps_between(solve_potts(values, sigmas, penalty))


def steps_between(segments: list[Segment]) -> list[Step]:
    """The jumps between consecutive segments of a fit."""
    steps = []
    for before, after in itertools.pairwise(segments):
        se = math.hypot(before.standard_error, after.standard_error)
        z = (after.level - before.level) / se
        steps.append(Step(before.stop - 1, after.start, before.level, after.level, se, one_sided_p(z),
                          one_sided_p(-z)))
    return steps


def robust_sigma_of_differences(differences) -> float:
    """The noise sd of a series from its consecutive differences (1.4826 MAD / sqrt 2 about 0):
    a few steps among many differences do not inflate it. NaN without differences."""
    d = np.abs(np.asarray([x for x in differences if math.isfinite(x)], dtype=np.float64))
    if d.size == 0:
        return math.nan
    return float(1.4826 * np.median(d) / math.sqrt(2.0))
