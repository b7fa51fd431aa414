"""Conclusions that survive seed noise: intervals over seeds and paired comparisons by seed
(docs/paper.md#how-sure).

Seeds are the unit of replication: a run's seed fixes its start and every random choice,
and two policies run with the same seed start from the same pose, so comparisons pair them
by seed. We use SciPy's resampling rather than code of our own:

- **Interval** of a mean over seeds: ``scipy.stats.bootstrap`` (BCa, 10,000 resamples, a
  fixed random seed so a table is reproducible), at 95 %. With fewer than 3 seeds there is
  none (NaN bounds); with all values equal, the interval is the mean itself.
- **Paired comparison** of two policies (or mappers) by seed: the mean difference, its
  bootstrap interval, and the two-sided p-value of a sign-flip permutation test
  (``scipy.stats.permutation_test``, ``permutation_type="samples"``: exact over all 2^S
  sign patterns when S is at most 16). With S seeds the smallest p-value an exact test can
  give is 2 / 2^S: 0.0625 for 5 seeds, so **5 seeds can never show a difference at 95 %**;
  6 is the fewest that can, and 10 leave room for moderate effects.

Shapes: S seeds.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import stats

LEVEL = 0.95
RESAMPLES = 10_000


class Interval(NamedTuple):
    mean: float
    low: float
    high: float

    def bounds(self, spec: str = ".2f") -> str:
        """The interval as text, ``[low, high]`` in format ``spec``; ``[< 3 seeds]`` where
        there is none (NaN bounds: too few seeds, or a NaN value, then also a NaN mean)."""
        if np.isfinite(self.low) and np.isfinite(self.high):
            return f"[{self.low:{spec}}, {self.high:{spec}}]"
        return "[< 3 seeds]" if np.isfinite(self.mean) else "[NaN values]"


class Paired(NamedTuple):
    """b - a by seed: the mean difference with its interval, the permutation test's p, and
    the standard deviation of the per-seed differences (ddof 1; nan under 2 seeds)."""

    diff: Interval
    p: float
    seeds: int
    sd: float = float("nan")

    @property
    def significant(self) -> bool:
        return self.p < 1 - LEVEL

    @property
    def in_sds(self) -> float:
        """The mean difference in standard deviations of the per-seed differences (an effect
        size: "ahead by more than one standard deviation" is ``in_sds > 1``)."""
        return self.diff.mean / self.sd if self.sd > 0 else float("nan")


def _seeds(values) -> np.ndarray:
    v = np.asarray(values, float)
    if v.ndim != 1:
        raise ValueError(f"values of shape {v.shape}: one per seed, (S,)")
    return v


def interval(values, level: float = LEVEL) -> Interval:
    """The mean of ``values`` (S,) and its bootstrap interval (NaN where a value is NaN)."""
    v = _seeds(values)
    mean = float(v.mean()) if len(v) else float("nan")
    if len(v) < 3 or not np.isfinite(v).all():
        return Interval(mean, float("nan"), float("nan"))
    if np.ptp(v) == 0:
        return Interval(mean, mean, mean)
    res = stats.bootstrap((v,), np.mean, confidence_level=level, n_resamples=RESAMPLES, method="BCa",
                          random_state=np.random.default_rng(0))
    low, high = res.confidence_interval
    if not (np.isfinite(low) and np.isfinite(high)):  # BCa degenerates on a few distinct values
        res = stats.bootstrap((v,), np.mean, confidence_level=level, n_resamples=RESAMPLES, method="percentile",
                              random_state=np.random.default_rng(0))
        low, high = res.confidence_interval
    return Interval(mean, float(low), float(high))


def paired(a, b, level: float = LEVEL) -> Paired:
    """Compare ``b`` with ``a``, both (S,) in seed order; a NaN value gives a NaN p (no
    finding), never a small one."""
    a, b = _seeds(a), _seeds(b)
    if a.shape != b.shape:
        raise ValueError(f"paired: {len(a)} and {len(b)} values: one per seed in each, in the same order")
    d = b - a
    if not len(d) or not np.isfinite(d).all():
        nan = float("nan")
        return Paired(Interval(float(d.mean()) if len(d) else nan, nan, nan), nan, len(d), nan)
    sd = float(d.std(ddof=1)) if len(d) > 1 else float("nan")
    if len(d) < 2 or np.all(d == d[0]):  # every sign pattern as far from 0 (or none): no resampling
        return Paired(interval(d, level), 1.0 if not d.any() else 2.0 ** (1 - len(d)), len(d), sd)
    test = stats.permutation_test((d,), np.mean, permutation_type="samples", alternative="two-sided",
                                  n_resamples=RESAMPLES, random_state=np.random.default_rng(0))
    return Paired(interval(d, level), float(test.pvalue), len(d), sd)


def tied_with_best(per_seed) -> dict:
    """{column: bool} for a table of values (S seeds x policies, a pandas DataFrame): the
    policy with the highest mean, and every policy a paired test by seed does not show to
    be behind it (the ones results tables print in bold). A policy missing some seeds (NaN)
    is paired on the seeds both ran."""
    best = per_seed.mean().idxmax()
    return {p: p == best or not paired(*per_seed[[p, best]].dropna().T.to_numpy()).significant
            for p in per_seed.columns}


def bold_cells(per_seed, policies, text) -> list[str]:
    """A results table's cells for ``policies`` (columns of ``per_seed``, S seeds x
    policies): ``text(policy, interval)``, in bold where :func:`tied_with_best`."""
    tied = tied_with_best(per_seed)
    cells = [text(p, interval(per_seed[p].dropna())) for p in policies]
    return [f"**{c}**" if tied[p] else c for p, c in zip(policies, cells)]


def seeds_needed(level: float = LEVEL) -> int:
    """The fewest seeds with which an exact sign-flip test can reach ``level``."""
    s = 1
    while 2.0 ** (1 - s) >= 1 - level:
        s += 1
    return s
