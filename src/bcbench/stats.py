"""Score statistics with 95% bootstrap confidence intervals (percentile method, seeded)."""

from __future__ import annotations

import functools
import math
from statistics import NormalDist
from typing import Any

import numpy as np

N_BOOT = 10_000
Z95 = 1.959964  # the normal 97.5% quantile: a two-sided 95% interval is +/- Z95 standard errors


def bootstrap_ci(values: np.ndarray, level: float = 0.95, n_boot: int = N_BOOT, seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of `values` (deterministic for a given seed)."""
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        return (float("nan"), float("nan"))
    if np.all(x == x[0]):  # every resample has the same mean
        return (float(x[0]), float(x[0]))
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, size=(n_boot, x.size))].mean(axis=1)
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [alpha, 1.0 - alpha])
    return (float(lo), float(hi))


def _aligned(*scores: dict[int, float]) -> list[np.ndarray]:
    """Each episode seed -> score map as an array over the seeds they all share, in seed order: the pairing."""
    seeds = sorted(set(scores[0]).intersection(*scores[1:]))
    return [np.array([d[k] for k in seeds], dtype=float) for d in scores]


def paired_bootstrap(a: dict[int, float], others: list[dict[int, float]], seed: int = 0, level: float = 0.95,
                     n_boot: int = N_BOOT) -> tuple[float, float, float, int]:
    """Mean of a - max(others) over the episode seeds all of them share, its paired percentile-bootstrap interval
    (seeds resampled together), and the number of shared seeds: the one paired comparison of bcbench.

    a and each of `others` map episode seed -> score. With several `others` the maximum is taken inside every
    resample, so choosing the best of them is part of what the interval accounts for.
    """
    x, *rest = _aligned(a, *others)
    n = len(x)
    if n == 0:
        return float("nan"), float("nan"), float("nan"), 0
    ys = np.stack(rest)  # (k, n)
    est = float(x.mean() - ys.mean(axis=1).max())
    idx = np.random.default_rng(seed).integers(0, n, size=(n_boot, n))
    boot = x[idx].mean(axis=1) - ys[:, idx].mean(axis=2).max(axis=0)  # (n_boot,)
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(boot, [alpha, 1.0 - alpha])
    return est, float(lo), float(hi), n


def recovered_share(sync: dict[int, float], naive: dict[int, float], other: dict[int, float], seed: int = 0,
                    level: float = 0.95, n_boot: int = N_BOOT, start: dict[int, float] | None = None
                    ) -> tuple[float, float, float, int]:
    """The share of naive's loss to delay that another strategy gets back: (other - naive) / (sync - naive), the
    three paired over the episode seeds they share, with a percentile-bootstrap interval (seeds resampled together,
    so numerator and denominator move as one), and the number of shared seeds. Issue 31's "half of naive async's
    loss recovered" is this share >= 0.5. Resamples where naive lost nothing (no share defined) are left out.

    `start`: the share of one step only, (other - start) / (sync - naive), e.g. a strategy over naive at the same
    execution horizon, so that a recovery splits into what the longer horizon buys and what the method adds
    (issue 74)."""
    s, a, o, *b = _aligned(sync, naive, other, *([start] if start is not None else []))  # (n,) each
    b0 = b[0] if b else a
    n = len(s)
    if n == 0:
        return float("nan"), float("nan"), float("nan"), 0
    loss = s.mean() - a.mean()
    est = float((o.mean() - b0.mean()) / loss) if loss > 0 else float("nan")
    idx = np.random.default_rng(seed).integers(0, n, size=(n_boot, n))
    num, den = o[idx].mean(axis=1) - b0[idx].mean(axis=1), s[idx].mean(axis=1) - a[idx].mean(axis=1)  # (n_boot,)
    boot = num[den > 0] / den[den > 0]
    if boot.size == 0:
        return est, float("nan"), float("nan"), n
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(boot, [alpha, 1.0 - alpha])
    return est, float(lo), float(hi), n


def _seed_arrays(seeds: list[dict[int, float]], others: list[list[dict[int, float]]] | None
                 ) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each training seed j: (n_j,) seeds[j]'s scores and (m, n_j) the others', on the episodes all share."""
    out = []
    for j in range(len(seeds)):
        shared = sorted(set(seeds[j]).intersection(*(o[j] for o in (others or []))))
        a = np.array([seeds[j][e] for e in shared])
        rest = np.array([[o[j][e] for e in shared] for o in (others or [])]).reshape(len(others or []), len(shared))
        out.append((a, rest))
    return out


def _words(rng: np.random.Generator, count: int) -> np.ndarray:
    """(>= count,) uint64: the next 32-bit words `rng.integers` would read (PCG64's next_uint32: a held high half first,
    then each 64-bit output's low half, then its high half), at least `count` of them and never half an output, so
    that a second call goes on where this one stopped. Advances `rng` past them; callers use `rng` no further."""
    state = rng.bit_generator.state
    held = [state["uinteger"]] if state["has_uint32"] else []
    if held:  # taken: random_raw neither reads nor clears it
        rng.bit_generator.state = {**state, "has_uint32": 0, "uinteger": 0}
    raw = rng.bit_generator.random_raw(max(0, -(-(count - len(held)) // 2)))  # (ceil,) uint64
    halves = np.stack([raw & 0xFFFFFFFF, raw >> np.uint64(32)], axis=1).reshape(-1)  # low, high, low, high, ...
    return np.concatenate([np.array(held, dtype=np.uint64), halves])


def bounded_draws(rng: np.random.Generator, bounds: np.ndarray) -> np.ndarray:
    """(N,) int64: what `[rng.integers(0, b) for b in bounds]` draws one call at a time (1 <= b < 2**32), in bulk.

    NumPy draws a bounded integer below 2**32 by Lemire's method (Lemire 2019, "Fast random integer generation in an
    interval", ACM TOMACS 29(1)): a 32-bit word x gives (x * b) >> 32 unless its low half (x * b) mod 2**32 falls
    under 2**32 mod b, when the word is dropped and the next one tried (rare: under b / 2**32). So the words are read
    in bulk, each kept or dropped by its own bound, and each drop shifts the rest by one word. A bound of 1 reads no
    word. Only for PCG64 (`np.random.default_rng`), whose word order this follows; tested equal to the calls."""
    if not isinstance(rng.bit_generator, np.random.PCG64):
        raise TypeError("bounded_draws follows PCG64's word order; got " + type(rng.bit_generator).__name__)
    b = np.asarray(bounds, dtype=np.uint64)
    if b.size and (b.min() < 1 or b.max() >= 2**32):
        raise ValueError("bounds must lie in [1, 2**32)")
    out = np.zeros(b.size, dtype=np.int64)
    live = np.flatnonzero(b > 1)  # a bound of 1 is 0 without a word
    b = b[live]
    threshold = (np.uint64(2**32) - b) % b  # 2**32 mod b, as NumPy computes it in 32 bits
    words = _words(rng, b.size + 64)
    i = shift = 0  # the next output to fill; the words dropped before it
    while i < b.size:
        if shift + b.size > words.size:  # more drops than the spare words: read more
            words = np.concatenate([words, _words(rng, b.size)])
        m = words[i + shift: shift + b.size] * b[i:]  # (N - i,) exact in 64 bits: both factors < 2**32
        dropped = (m & np.uint64(0xFFFFFFFF)) < threshold[i:]
        stop = int(np.argmax(dropped)) if dropped.any() else b.size - i
        out[live[i:i + stop]] = (m[:stop] >> np.uint64(32)).astype(np.int64)
        i, shift = i + stop, shift + 1
    return out


def _resampled_means(per_seed: list[tuple[np.ndarray, np.ndarray]], rng: np.random.Generator, n_boot: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The two-level bootstrap's draws: per resample b and slot i, a training seed j drawn with replacement and its
    episodes drawn with replacement; returns (n_boot, k) the mean of a over them and (n_boot, k, m) the others'.

    The random draws are those a plain double loop makes one call at a time (all seeds first, then each slot's
    episodes, `rng.integers(0, n_j, n_j)`), read in bulk (`bounded_draws`), so intervals stay bit-identical to it;
    the means are taken per training seed along a contiguous last axis (the same pairwise sum as a 1-D mean)."""
    k = len(per_seed)
    m = per_seed[0][1].shape[0]
    draws = rng.integers(0, k, size=(n_boot, k)).ravel()  # training seeds, with replacement, in slot order
    n = np.array([a.size for a, _ in per_seed])[draws]  # (n_boot * k,) each slot's episode count
    episodes = bounded_draws(rng, np.repeat(n, n))  # each slot's n_j episode draws, in order
    starts = np.cumsum(n) - n  # where each slot's draws begin
    ma, mr = np.empty((n_boot, k)), np.empty((n_boot, k, m))
    for j, (a, rest) in enumerate(per_seed):
        where = np.flatnonzero(draws == j)  # the (b, slot) positions that drew seed j, in draw order
        if where.size == 0:
            continue
        idx = episodes[starts[where][:, None] + np.arange(a.size)]  # (count_j, n_j)
        ma.reshape(-1)[where] = a[idx].mean(axis=1)
        if m:
            mr.reshape(-1, m)[where] = rest[:, idx].mean(axis=2).T  # (count_j, m)
    return ma, mr


def two_level_bootstrap(seeds: list[dict[int, float]], others: list[list[dict[int, float]]] | None = None,
                        seed: int = 0, level: float = 0.95, n_boot: int = N_BOOT) -> dict[str, Any]:
    """Mean over training seeds of each seed's mean episode score, with an interval that resamples training seeds
    and, within each drawn seed, its episodes (a two-level bootstrap).

    `seeds[j]` maps episode seed -> score for training seed j. With `others` (one list per alternative, the same
    training seeds in the same order) the statistic is paired: a - max(others), differences taken per episode seed
    within each training seed (shared episode seeds only), the maximum inside every resample. Also returns the
    share of the variance that comes from training seeds (between-seed variance of the seed means over it plus the
    mean within-seed variance of a seed mean): how much of the interval a single training seed would hide.
    """
    groups = [seeds, *(others or [])]
    k = len(seeds)
    if k == 0 or any(len(g) != k for g in groups):
        raise ValueError("every alternative needs the same training seeds as the first")
    rng = np.random.default_rng(seed)
    per_seed = _seed_arrays(seeds, others)

    def stat(means_a: np.ndarray, means_rest: np.ndarray) -> np.ndarray:
        return means_a - (means_rest.max(axis=0) if means_rest.size else 0.0)

    point = stat(np.array([a.mean() for a, _ in per_seed]).mean(),
                 np.array([r.mean(axis=1) for _, r in per_seed]).mean(axis=0) if others else np.empty(0))
    ma, mr = _resampled_means(per_seed, rng, n_boot)  # (n_boot, k), (n_boot, k, m)
    boot = stat(ma.mean(axis=1), mr.mean(axis=1).T)  # (n_boot,): the statistic of each resample
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(boot, [alpha, 1.0 - alpha])
    diffs = [a - (r.max(axis=0) if r.size else 0.0) for a, r in per_seed]  # per-episode statistic, per seed
    seed_means = np.array([d.mean() for d in diffs])
    between = float(seed_means.var(ddof=1)) if k > 1 else 0.0
    within = float(np.mean([d.var(ddof=1) / d.size for d in diffs if d.size > 1])) if diffs else 0.0
    share = between / (between + within) if between + within > 0 else 0.0
    return {"value": float(point), "ci95": [float(lo), float(hi)], "per_seed": seed_means.tolist(),
            "training_seed_share": share, "training_seeds": k}


@functools.cache  # a report asks for the same few (p, df) hundreds of times
def t_quantile(p: float, df: int) -> float:
    """The p-quantile of Student's t with `df` degrees of freedom (p in (0, 1)), to about 1e-9.

    Bisection on the CDF, F(x) = 1/2 + the density's integral from 0 to x (Simpson's rule over 4,096 intervals): no
    scipy in the core, and only small df (training seeds - 1) are ever asked for."""
    if not 0.0 < p < 1.0 or df < 1:
        raise ValueError(f"need 0 < p < 1 and df >= 1, got p={p}, df={df}")
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    log_c = math.lgamma((df + 1) / 2) - math.lgamma(df / 2) - 0.5 * math.log(df * math.pi)

    def half_mass(x: float) -> float:  # integral of the density over [0, x]
        t = np.linspace(0.0, x, 4097)
        f = np.exp(log_c - (df + 1) / 2 * np.log1p(t * t / df))
        return float((x / 4096 / 3) * (f[0] + f[-1] + 4 * f[1:-1:2].sum() + 2 * f[2:-1:2].sum()))

    lo, hi = 0.0, 1.0
    while half_mass(hi) < p - 0.5:
        lo, hi = hi, 2 * hi
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if half_mass(mid) < p - 0.5 else (lo, mid)
    return (lo + hi) / 2


def over_training_seeds(seeds: list[dict[int, float]], others: list[list[dict[int, float]]] | None = None,
                        seed: int = 0, level: float = 0.95, n_boot: int = N_BOOT) -> dict[str, Any]:
    """Mean over training seeds of each seed's mean score (or, with `others`, of the paired difference a - the best of
    them), with a t interval over the k training seeds (k - 1 degrees of freedom) and, beside it, the two-level
    bootstrap's (`two_level_bootstrap`, whose variance share this also returns).

    Why not the bootstrap alone: with k = 3 training seeds a percentile bootstrap that resamples them covers the
    true mean far less often than stated when training seeds carry most of the variance (about 80-85% for a nominal
    95%: `benchmarks/seed_intervals.py`, results/seed-intervals/). Each seed's value is one draw of (seed effect +
    the mean of its episodes), so Student's t over the k values, t_{k-1} s / sqrt(k), is exact for a balanced
    design under normality (4.30 for k = 3: wide, the honest price of three seeds; Cameron & Miller 2015 on few
    clusters). Three seeds that happen to agree can make it narrower than their episodes allow, so the half-width is
    the wider of it and the episodes-only one, z sqrt(mean_j(var_j / n_j) / k) (which 100 episodes per seed estimate
    well): the Hartung-Knapp interval of an equal-weight random-effects meta-analysis, widened to the standard
    interval where that is wider, as Jackson, Law, Ruecker & Schwarzer (2017, "The Hartung-Knapp modification for
    random-effects meta-analysis: a useful refinement but are there any residual concerns?", Stat. Med. 36) propose.
    It always contains the exact t interval, so it covers at least as often. With `others` the best alternative is
    the one with the highest mean over every seed (fixed, so the seeds' values average to the estimate); the
    bootstrap resamples that choice too. With one training seed there is no t interval: "ci95" is the episode
    bootstrap's."""
    boot = two_level_bootstrap(seeds, others, seed=seed, level=level, n_boot=n_boot)
    k = len(seeds)
    out = {**boot, "ci95_bootstrap": boot["ci95"], "interval": "two-level bootstrap"}
    if k < 2:
        return out
    arrays = _seed_arrays(seeds, others)  # per seed: (n_j,) a and (m, n_j) the others, on shared episodes
    best = int(np.argmax(np.mean([r.mean(axis=1) for _, r in arrays], axis=0))) if others else None
    per_episode = [a - r[best] if others else a for a, r in arrays]  # (n_j,) each: a, or a minus the chosen best
    v = np.array([x.mean() for x in per_episode])  # (k,) each seed's value
    within = float(np.mean([x.var(ddof=1) / x.size for x in per_episode if x.size > 1]))
    half = max(t_quantile((1 + level) / 2, k - 1) * float(v.std(ddof=1)), NormalDist().inv_cdf((1 + level) / 2)
               * math.sqrt(within)) / math.sqrt(k)
    return {**out, "value": float(v.mean()), "ci95": [float(v.mean() - half), float(v.mean() + half)],
            "per_seed": v.tolist(), "within_var": within, "interval": f"t over {k} training seeds"}


def seeds_to_decide(per_seed: list[float], within_var: float, bounds: list[float], level: float = 0.95,
                    most: int = 50) -> int | None:
    """How many training seeds would put `over_training_seeds`' interval wholly on one side of every bound, if the
    estimate (the mean of `per_seed`), the spread of the per-seed values and the within-seed variance of a seed's
    value (`within_var`) stayed as they are: a projection for planning the next run, not a result. None when more
    than `most` would be needed (an estimate on a bound needs infinitely many)."""
    v = np.asarray(per_seed, dtype=np.float64)
    est, sd = float(v.mean()), float(v.std(ddof=1))
    z = NormalDist().inv_cdf((1 + level) / 2)
    for k in range(2, most + 1):
        half = max(t_quantile((1 + level) / 2, k - 1) * sd, z * math.sqrt(within_var)) / math.sqrt(k)
        if all(abs(est - b) > half for b in bounds):
            return k
    return None


def episodes_to_show_within(sd: float, margin: float, diff: float = 0.0, power: float = 0.8,
                            level: float = 0.95) -> float:
    """Paired episodes needed for the `level` interval of a difference to lie above -margin with probability `power`,
    when the true difference is `diff` and the per-episode differences have standard deviation `sd`.

    The non-inferiority sample size under the normal approximation: the interval's lower bound sits
    z_{(1+level)/2} standard errors below the mean, so n = ((z_{(1+level)/2} + z_power) sd / (margin + diff))^2.
    inf where diff <= -margin: no number of episodes shows such a setting within the margin."""
    if margin + diff <= 0:
        return float("inf")
    z = NormalDist().inv_cdf((1 + level) / 2) + NormalDist().inv_cdf(power)
    return float((z * sd / (margin + diff)) ** 2)


def estimate(values: np.ndarray, seed: int = 0) -> dict[str, Any]:
    """Mean with its 95% interval, as stored in result files."""
    x = np.asarray(values, dtype=np.float64)
    lo, hi = bootstrap_ci(x, seed=seed)
    return {"value": float(x.mean()) if x.size else float("nan"), "ci95": [lo, hi]}


def score_summary(scores: np.ndarray, success: np.ndarray, final_coverage: np.ndarray) -> dict[str, Any]:
    """The study's metrics: mean score, share of scores > 0.5 and > 0.9, plus success rate."""
    scores = np.asarray(scores, dtype=np.float64)
    return {
        "n": int(scores.size),
        "mean_score": estimate(scores),
        "share_above_0.5": estimate(scores > 0.5),
        "share_above_0.9": estimate(scores > 0.9),
        "success_rate": estimate(np.asarray(success, dtype=np.float64)),
        "mean_final_coverage": estimate(np.asarray(final_coverage, dtype=np.float64)),
    }


def intervals_overlap(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether two `estimate` intervals overlap."""
    return not (a["ci95"][1] < b["ci95"][0] or b["ci95"][1] < a["ci95"][0])


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a share k / n (never [0, 0] at 0%, unlike a percentile bootstrap)."""
    if n <= 0:
        return (float("nan"), float("nan"))
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (float(max(0.0, centre - half)), float(min(1.0, centre + half)))


def fmt_share(e: dict[str, Any], n: int) -> str:
    """'22.0% [15.0, 31.0]': a share with its Wilson 95% interval, from a stored estimate's value and n."""
    k = round(e["value"] * n)
    lo, hi = wilson(k, n)
    return f"{100 * e['value']:.1f}% [{100 * lo:.1f}, {100 * hi:.1f}]"


def fmt_estimate(e: dict[str, Any], pct: bool = False) -> str:
    """'0.41 [0.33, 0.49]' or '40.0% [25.0, 55.0]'."""
    v, (lo, hi) = e["value"], e["ci95"]
    if pct:
        return f"{100 * v:.1f}% [{100 * lo:.1f}, {100 * hi:.1f}]"
    return f"{v:.3f} [{lo:.3f}, {hi:.3f}]"
