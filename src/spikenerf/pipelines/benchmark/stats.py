"""Error bars over seeds: mean ± standard deviation, and paired differences with Student-t 95% intervals.

A benchmark cell is one (scene, colour, method variant, seed) run. Tables aggregate the seeds of a
(scene, colour, variant) to mean ± sample standard deviation (ddof = 1). The ``differences`` table pairs two
variants on the same (scene, seed) and gives the mean difference with a two-sided Student-t confidence
interval over those pairs. Pairs from one scene share that scene's effect, so a second interval is computed
over the per-seed means (each over the scenes every seed has, ``seeds − 1`` degrees of freedom); a claim is
"shown" only when both intervals exclude 0 on the claimed side.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from spikenerf.pipelines.benchmark.variants import COMPARISONS


@dataclass(frozen=True)
class Cell:
    """One finished (scene, method variant, colour, seed) run and its mean test metrics (None = n/a):
    ``eval_seconds`` the wall time of its evaluation (``metrics.json``), ``train_seconds`` its training time
    (``summary.json``: optimisation only, evaluation excluded)."""

    scene: str
    variant: str
    color: str
    psnr: float
    ssim: float
    lpips: float | None = None
    eval_seconds: float | None = None
    seed: int = 0
    train_seconds: float | None = None

    @classmethod
    def from_dict(cls, data: dict) -> Cell:
        """A cell of ``results.json`` (``seconds``, its name before ``eval_seconds``, is read as such).

        Raises:
            TypeError: a field is missing or unknown.
        """
        data = dict(data)
        if "seconds" in data and "eval_seconds" not in data:
            data["eval_seconds"] = data.pop("seconds")
        return cls(**data)


#: metric name -> True when higher is better
HIGHER_IS_BETTER = {"ssim": True, "psnr": True, "lpips": False}

DIFF_METRICS = ("psnr", "ssim", "lpips")
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Stat:
    """Mean and sample standard deviation (None for a single value) of ``n`` values."""

    mean: float
    std: float | None
    n: int


def summarize(values: Sequence[float | None]) -> Stat | None:
    """Mean ± sample std (ddof = 1) of ``values``; None when any value is missing (None or NaN) or none."""
    if not values or any(v is None or math.isnan(v) for v in values):
        return None
    vals = [float(v) for v in values if v is not None]
    mean = sum(vals) / len(vals)
    std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else None
    return Stat(mean, std, len(vals))


def t_quantile(p: float, dof: int) -> float:
    """The ``p`` quantile of Student's t distribution with ``dof`` degrees of freedom (scipy)."""
    from scipy.stats import t

    return float(t.ppf(p, dof))


@dataclass(frozen=True)
class Difference:
    """One paired difference ``ours − baseline`` of ``metric`` in ``color`` over ``n`` (scene, seed) pairs.

    ``low``/``high`` bound the two-sided 95% Student-t interval (None with fewer than 2 pairs);
    ``seed_low``/``seed_high`` the same over the per-seed means (None with fewer than 2 seeds). ``verdict``
    is "shown" when both intervals exclude 0 on the claimed side (higher PSNR/SSIM, lower LPIPS), "not shown"
    when one contains 0 or cannot be computed, and "not shown (reversed)" when the pair interval excludes 0
    on the other side.
    """

    ours: str
    baseline: str
    color: str
    metric: str
    n: int
    mean: float
    std: float | None
    low: float | None
    high: float | None
    verdict: str
    seed_low: float | None = None
    seed_high: float | None = None


def t_interval(values: Sequence[float]) -> tuple[float, float] | None:
    """The two-sided 95% Student-t interval of the mean of ``values`` (None for fewer than 2)."""
    stat = summarize(values)
    if stat is None or stat.std is None:
        return None
    half = t_quantile(0.5 + CONFIDENCE / 2, stat.n - 1) * stat.std / math.sqrt(stat.n)
    return stat.mean - half, stat.mean + half


def _claimed(interval: tuple[float, float] | None, better: bool) -> bool:
    """Whether ``interval`` excludes 0 on the claimed side; an interval of no width (every difference the
    same) claims nothing: its spread was not measured."""
    if interval is None or not interval[1] > interval[0]:
        return False
    return interval[0] > 0 if better else interval[1] < 0


def paired_difference(
    ours: str, baseline: str, color: str, metric: str, diffs: Sequence[float], per_seed: Sequence[float]
) -> Difference:
    """The mean of ``diffs`` (ours − baseline, one per pair) with its t interval and verdict.

    ``per_seed``: the mean difference of each training seed over the scenes all seeds share
    (:func:`seed_means`; [] where they share none). With one seed the pair interval only covers scene to
    scene spread, not seed noise, so no claim is 'shown' ("not shown (one seed)").
    """
    stat = summarize(diffs)
    if stat is None:
        raise ValueError("paired_difference needs at least one difference")
    pairs, seeds, better = t_interval(diffs), t_interval(per_seed), HIGHER_IS_BETTER[metric]
    verdict = "not shown"
    if pairs is not None and len(per_seed) == 1:
        verdict = "not shown (one seed)"
    elif _claimed(pairs, better) and _claimed(seeds, better):
        verdict = "shown"
    elif _claimed(pairs, not better):
        verdict = "not shown (reversed)"
    low, high = pairs or (None, None)
    seed_low, seed_high = seeds or (None, None)
    return Difference(ours, baseline, color, metric, stat.n, stat.mean, stat.std, low, high, verdict,
                      seed_low, seed_high)  # fmt: skip


def seed_means(by_seed: dict[int, dict[str, float]]) -> list[float]:
    """Each seed's mean difference over the scenes that every seed has (``by_seed``: seed → scene →
    difference), so that no seed's mean has other scenes in it than another's (unfinished cells); one seed:
    its mean over its scenes; [] where two or more seeds share no scene."""
    if len(by_seed) == 1:
        return [sum(d.values()) / len(d) for d in by_seed.values()]
    shared = set.intersection(*(set(scenes) for scenes in by_seed.values())) if by_seed else set()
    return [sum(d[scene] for scene in shared) / len(shared) for d in by_seed.values()] if shared else []


def differences(
    cells: Sequence[Cell],
    colors: Sequence[str],
    comparisons: Sequence[tuple[str, str]] = COMPARISONS,
    metrics: Sequence[str] = DIFF_METRICS,
) -> list[Difference]:
    """Every claimed difference whose two variants both have cells, per colour and metric.

    Pairs are the (scene, seed) keys where both variants have a value of the metric (LPIPS may be None).
    """
    value = {(c.scene, c.seed, c.color, c.variant): c for c in cells}
    out = []
    for ours, base in comparisons:
        for color in colors:
            keys = sorted({(s, k) for s, k, col, v in value if col == color and v == ours})
            for metric in metrics:
                diffs, by_seed = [], {}
                for scene, seed in keys:
                    a, b = value[(scene, seed, color, ours)], value.get((scene, seed, color, base))
                    x, y = getattr(a, metric), None if b is None else getattr(b, metric)
                    if x is not None and y is not None and math.isfinite(x - y):  # not NaN, not inf − inf
                        diffs.append(x - y)
                        by_seed.setdefault(seed, {})[scene] = x - y
                if diffs:
                    out.append(paired_difference(ours, base, color, metric, diffs, seed_means(by_seed)))
    return out
