"""Exact binomial statistics for counts of rare events (false positives): intervals, ratios, sample sizes."""

from __future__ import annotations

import math

import numpy as np

from factorloc.benchmarking.results import CountComparison, ModeFigures
from factorloc.errors import InputError

__all__ = [
    "check_confidence",
    "clopper_pearson",
    "compare_counts",
    "power_to_show_ratio",
    "queries_to_show_ratio",
    "rate_ratio_interval",
]


def _beta_ppf(q: float | np.ndarray, a: float | np.ndarray, b: float | np.ndarray) -> float | np.ndarray:
    from scipy.stats import beta  # scipy.stats is imported on first use (~0.4 s)

    return beta.ppf(q, a, b)


def _check_count(count: int, trials: int) -> None:
    if not (0 <= count <= trials):
        raise InputError(f"need 0 <= count <= trials, got count={count!r}, trials={trials!r}")


def check_confidence(confidence: float) -> None:
    if not 0.0 < confidence < 1.0:
        raise InputError(f"confidence must be in (0, 1), got {confidence!r}")


def clopper_pearson(count: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper–Pearson) two-sided interval of the binomial rate ``count / trials``.

    ``[B(α/2; k, n − k + 1), B(1 − α/2; k + 1, n − k)]`` with ``B(q; a, b)`` the
    beta distribution's quantile and ``α = 1 − confidence`` (Clopper & Pearson,
    Biometrika 26, 1934); the lower end is 0 when ``k = 0``, the upper 1 when
    ``k = n``. ``(nan, nan)`` with no trial.
    """
    _check_count(count, trials)
    check_confidence(confidence)
    if trials == 0:
        return math.nan, math.nan
    a = 1.0 - confidence
    lo = 0.0 if count == 0 else float(_beta_ppf(a / 2.0, count, trials - count + 1))
    hi = 1.0 if count == trials else float(_beta_ppf(1.0 - a / 2.0, count + 1, trials - count))
    return lo, hi


def _ratio_of_share(share: float, trials_num: float, trials_den: float) -> float:
    """ρ from the conditional share π = ρ·n₁ / (ρ·n₁ + n₂): ρ = π·n₂ / ((1 − π)·n₁)."""
    if share >= 1.0:
        return math.inf
    return share * trials_den / ((1.0 - share) * trials_num)


def rate_ratio_interval(
    count_num: float,
    trials_num: float,
    count_den: float,
    trials_den: float,
    confidence: float = 0.95,
    *,
    one_sided: bool = False,
) -> tuple[float, float]:
    """Exact conditional interval of the ratio ρ of two rare-event rates, ``(k₁/n₁) / (k₂/n₂)``.

    Given the total ``m = k₁ + k₂``, ``k₁`` is binomial(m, π) with
    ``π = ρ·n₁ / (ρ·n₁ + n₂)`` (Poisson approximation of rare events: the
    classical exact test of two rates, e.g. Breslow & Day 1987, §2.2); the
    Clopper–Pearson interval of π maps to ρ. With ``one_sided`` the result is
    ``(lower bound at confidence, inf)``. ``(nan, nan)`` when ``m = 0``: no
    event on either side, nothing to compare. Counts may be non-integer
    (expected counts, :func:`queries_to_show_ratio`).
    """
    check_confidence(confidence)
    if min(count_num, count_den) < 0 or min(trials_num, trials_den) <= 0:
        raise InputError(f"counts must be >= 0 and trials > 0, got {count_num!r}/{trials_num!r} and {count_den!r}/{trials_den!r}")
    if count_num + count_den == 0:
        return math.nan, math.nan
    a = 1.0 - confidence
    q_lo = a if one_sided else a / 2.0
    lo = 0.0 if count_num == 0 else float(_beta_ppf(q_lo, count_num, count_den + 1))
    if one_sided:
        return _ratio_of_share(lo, trials_num, trials_den), math.inf
    hi = 1.0 if count_den == 0 else float(_beta_ppf(1.0 - a / 2.0, count_num + 1, count_den))
    return _ratio_of_share(lo, trials_num, trials_den), _ratio_of_share(hi, trials_num, trials_den)


def power_to_show_ratio(queries: int, rate_num: float, rate_den: float, target: float = 5.0, confidence: float = 0.95) -> float:
    """Probability that ``queries`` per mode show ``ratio ≥ target`` if the rates are the true ones.

    Exact: the sum, over the binomial counts ``k₁ ~ B(n, rate_num)``,
    ``k₂ ~ B(n, rate_den)`` (independent), of the probability of the pairs whose
    one-sided lower bound (:func:`rate_ratio_interval`) reaches ``target``
    (tails below 1e-12 left out).
    """
    if queries < 1 or not (0.0 <= rate_num <= 1.0 and 0.0 <= rate_den <= 1.0):
        raise InputError(f"need queries >= 1 and rates in [0, 1], got {queries!r}, {rate_num!r}, {rate_den!r}")
    check_confidence(confidence)

    from scipy.stats import binom as binom_dist

    def support(p: float) -> np.ndarray:
        lo, hi = binom_dist.ppf(1e-12, queries, p), binom_dist.isf(1e-12, queries, p)
        return np.arange(int(lo), int(hi) + 1)

    k1, k2 = support(rate_num), support(rate_den)
    p1, p2 = binom_dist.pmf(k1, queries, rate_num), binom_dist.pmf(k2, queries, rate_den)
    a1, a2 = np.meshgrid(k1.astype(np.float64), k2.astype(np.float64), indexing="ij")
    with np.errstate(all="ignore"):
        share = np.where(a1 > 0, _beta_ppf(1.0 - confidence, np.maximum(a1, 1e-300), a2 + 1.0), 0.0)
        # ρ ≥ target ⇔ π ≥ target / (1 + target) for equal sample sizes
        shown = share >= target / (1.0 + target)
    return float(np.sum(np.outer(p1, p2)[shown]))


def queries_to_show_ratio(
    rate_num: float,
    rate_den: float,
    target: float = 5.0,
    confidence: float = 0.95,
    *,
    power: float | None = None,
    max_queries: int = 10**7,
) -> int | None:
    """Fewest queries (per mode) that would show ``rate_num / rate_den ≥ target``.

    Without ``power``: the one-sided lower bound of :func:`rate_ratio_interval`
    computed on the *expected* counts ``n·rate`` must reach ``target`` — about an
    even chance of showing it with that many queries if the rates are the true
    ones. With ``power``: :func:`power_to_show_ratio` must reach it (found by
    bisection; the exact power is slightly saw-toothed in n). ``None`` when
    ``rate_num`` is 0 or the ratio of the rates does not exceed ``target`` (no
    number of queries would show it), or beyond ``max_queries``. With
    ``rate_den = 0`` and no power this is the closed form
    ``n·rate_num ≥ ln α / ln(target / (1 + target))`` (16.4 events for 5× at 95 %).
    """
    if not (rate_num >= 0.0 and rate_den >= 0.0 and target > 0.0):
        raise InputError(f"rates must be >= 0 and target > 0, got {rate_num!r}, {rate_den!r}, {target!r}")
    if power is not None and not 0.0 < power < 1.0:
        raise InputError(f"power must be in (0, 1), got {power!r}")
    if rate_num == 0.0 or rate_num <= target * rate_den:
        return None

    def shown(n: int) -> bool:
        if power is not None:
            return power_to_show_ratio(n, rate_num, rate_den, target, confidence) >= power
        return rate_ratio_interval(n * rate_num, n, n * rate_den, n, confidence, one_sided=True)[0] >= target

    hi = 1
    while not shown(hi):
        hi *= 2
        if hi > max_queries:
            return None
    lo = hi // 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if shown(mid) else (mid, hi)
    return hi


def _mode_figures(count: int, trials: int, confidence: float, reliable: int | None = None) -> ModeFigures:
    rate_ci = clopper_pearson(int(count), int(trials), confidence)
    if reliable is None:
        return ModeFigures(int(count), int(trials), count / trials if trials else math.nan, rate_ci)
    per = count / reliable if reliable else math.nan
    per_ci = clopper_pearson(int(count), int(reliable), confidence) if reliable else (math.nan, math.nan)
    return ModeFigures(int(count), int(trials), count / trials if trials else math.nan, rate_ci, int(reliable), per, per_ci)


def compare_counts(
    seeded_count: int,
    blind_count: int,
    queries: int,
    *,
    confidence: float = 0.95,
    target: float = 5.0,
    seeded_reliable: int | None = None,
    blind_reliable: int | None = None,
) -> CountComparison:
    """Blind vs seeded false positives on the same ``queries``: rates, ratio and their exact intervals.

    Returns ``seeded`` / ``blind`` (``count``, ``queries``, ``rate`` and its
    Clopper–Pearson ``rate_ci``; with reliable counts also ``per_reliable`` and
    its interval), ``ratio`` = blind / seeded rate (``inf`` when only blind has
    some, ``nan`` when neither), ``ratio_ci`` (two-sided, :func:`rate_ratio_interval`),
    ``ratio_lower_bound`` (one-sided at ``confidence``), ``shows_target``
    (that bound ≥ ``target``) and ``queries_needed`` (:func:`queries_to_show_ratio`
    at the observed rates, a seeded 0 taken as 0: the best case; ``None`` when
    the observed rates could never show it; ``queries_needed_power_80``: for an
    80 % chance, :func:`power_to_show_ratio`).
    """
    if queries < 1:
        raise InputError(f"queries must be >= 1, got {queries!r}")
    if seeded_count == blind_count == 0:
        ratio = math.nan
    else:
        ratio = blind_count / seeded_count if seeded_count else math.inf
    lower = rate_ratio_interval(blind_count, queries, seeded_count, queries, confidence, one_sided=True)[0]
    rates = (blind_count / queries, seeded_count / queries)
    return CountComparison(
        seeded=_mode_figures(seeded_count, queries, confidence, seeded_reliable),
        blind=_mode_figures(blind_count, queries, confidence, blind_reliable),
        ratio=ratio,
        ratio_ci=rate_ratio_interval(blind_count, queries, seeded_count, queries, confidence),
        ratio_lower_bound=lower,
        shows_target=bool(lower >= target),  # nan >= target is False
        queries_needed=queries_to_show_ratio(*rates, target, confidence),
        queries_needed_power_80=queries_to_show_ratio(*rates, target, confidence, power=0.8),
    )
