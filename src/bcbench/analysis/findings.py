"""The study's five findings, each judged on this run's evidence: supported, contradicted or inconclusive.

Every verdict rests on one pre-specified paired comparison (or a fixed set of them): the per-seed score
differences of two settings evaluated on the same episode seeds, with a 95% paired-bootstrap interval of
their mean (over several training seeds, a t interval over the seeds' mean differences: `paired_interval`), set
against an equivalence margin m (default 0.05 mean score, `margin` in the study spec).
A claim is supported when the interval lies inside the margin or beyond it in the claimed direction,
contradicted when it lies wholly on the other side, and inconclusive otherwise. A finding that rests on
a policy not shown converged (its twice-the-steps check, or in older studies its learning curve: the report's
"Training: converged?") reads "undertrained" instead of a verdict.
Each finding's `rule` states its test in one sentence (printed in the report).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

from bcbench.stats import over_training_seeds, paired_bootstrap, seeds_to_decide

SUPPORTED, CONTRADICTED, INCONCLUSIVE, UNDERTRAINED = "supported", "contradicted", "inconclusive", "undertrained"
DEFAULT_MARGIN = 0.05
SLOWER = 10.0  # finding 1 compares the slowest setting with the settings at least this many times faster
# a setting whose speed-up lies within this fraction of SLOWER is on the line: two interleaved runs an hour apart on
# one VM put flow Euler-10 at 10.0x and 9.4x DDPM-100 (results/cpu-confirm); what the paired comparison reads with
# it on the other side is shown beside the rule's verdict (not instead of it)
BORDER = 0.1


@dataclass
class Point:
    """What a finding needs of one evaluated setting."""

    name: str
    policy: str
    variant: str  # "default" or e.g. "ddpm10", "ddim10-leading"
    score: float
    ci: tuple[float, float]
    latency_ms: float | None
    beta_schedule: str | None = None
    scores: dict[int, float] = field(default_factory=dict)  # episode seed -> score
    converged: bool | None = None  # False: not shown converged (a failed or missing check)
    run: str = ""  # the trained run's label (its variants share one learning curve)
    seeds: list[dict[int, float]] = field(default_factory=list)  # several training seeds: each one's `scores`
    seed_ids: list[int] = field(default_factory=list)
    train_seed: int | None = None  # a single trained run's seed (None: a baseline, or several seeds in `seeds`)
    timed: str = ""  # where latency_ms comes from when not the study's own timing block (`with_interleaved`)
    timed_at: str = ""  # its latency record's `created` (ISO UTC, the timing stage's start): which sitting timed it


class Diff(NamedTuple):
    """A paired difference: estimate, 95% interval, shared episodes, training seeds resampled (1: episodes only)
    and the share of its variance that comes from training seeds (None with one seed)."""

    est: float
    lo: float
    hi: float
    n: int
    k: int = 1
    share: float | None = None
    fixed: tuple[str, ...] = ()  # single trained runs paired with every training seed of the others (held fixed)
    boot: tuple[float, float] | None = None  # several training seeds: the two-level bootstrap's interval, shown beside
    per_seed: tuple[float, ...] = ()  # several training seeds: each seed's difference (for `seeds_note`)
    within_var: float | None = None  # and the within-seed variance of one seed's difference


@dataclass
class Finding:
    number: int
    claim: str
    verdict: str
    evidence: str
    rule: str = ""
    evaluated: bool = True  # False: inconclusive for want of the settings it compares, not for a wide interval
    bound: str = ""  # "ceiling" / "floor": every episode of every setting compared scored 1.0 / 0.0 (`_bound`)


def _by_training_seed(p: Point, ids: list[int]) -> list[dict[int, float]]:
    """p's episode scores for each training seed in `ids` (one run, or a baseline, stands for every seed)."""
    if not p.seeds:
        return [p.scores] * len(ids)
    own = dict(zip(p.seed_ids, p.seeds, strict=True))
    return [own[i] for i in ids]


def paired_interval(a: Point, others: list[Point], seed: int = 0) -> Diff:
    """Mean of a - max(others) over shared episode seeds with its 95% paired-bootstrap interval
    (bcbench.stats.paired_bootstrap). Where a setting has several training seeds, the difference is taken per episode
    within each training seed the settings share, and the interval is a t interval over the training seeds' paired
    differences (bcbench.stats.over_training_seeds; the two-level bootstrap's is kept beside it); a single run or a
    baseline is paired with every seed of the other."""
    multi = [p for p in (a, *others) if p.seeds]
    if not multi:
        return Diff(*paired_bootstrap(a.scores, [o.scores for o in others], seed))
    ids = sorted(set(multi[0].seed_ids).intersection(*(p.seed_ids for p in multi[1:])))
    if not ids:
        return Diff(float("nan"), float("nan"), float("nan"), 0)
    mine, rest = _by_training_seed(a, ids), [_by_training_seed(o, ids) for o in others]
    est = over_training_seeds(mine, rest, seed)
    n = len(set(mine[0]).intersection(*(r[0] for r in rest)))
    fixed = tuple(f"{p.name} (s{p.train_seed})" for p in (a, *others) if held_fixed(p))
    if len(ids) < 2:
        return Diff(est["value"], *est["ci95"], n, len(ids), est["training_seed_share"], fixed)
    return Diff(est["value"], *est["ci95"], n, len(ids), est["training_seed_share"], fixed,
                tuple(est["ci95_bootstrap"]), tuple(est["per_seed"]), est["within_var"])


def held_fixed(p: Point) -> bool:
    """A single trained run: against settings with several training seeds it is paired with each of them."""
    return not p.seeds and p.train_seed is not None


def _fixed_note(d: Diff) -> str:
    """'; X (s0) has one training seed, held fixed: its seed-to-seed variance is not in the interval', or ''.

    Until every seed of a study is trained, a single trained run meets settings with several; it is paired with each
    of their seeds, so the interval says nothing about how much another training seed of it would differ."""
    if not d.fixed:
        return ""
    verb = "has" if len(d.fixed) == 1 else "have"
    return (f"; {' and '.join(d.fixed)} {verb} one training seed, held fixed: its seed-to-seed variance is not in "
            f"the interval")


def _fmt(p: Point) -> str:
    lat = f", {p.latency_ms:.1f} ms" if p.latency_ms is not None else ""
    seeds = f" (mean of {len(p.seeds)} training seeds)" if p.seeds else ""
    return f"{p.name} {p.score:.3f} [{p.ci[0]:.3f}, {p.ci[1]:.3f}]{seeds}{lat}"


def _fmt_diff(d: Diff) -> str:
    if d.k == 1:
        return f"paired difference {d.est:+.3f} [{d.lo:+.3f}, {d.hi:+.3f}] over {d.n} seeds"
    boot = f"; two-level bootstrap [{d.boot[0]:+.3f}, {d.boot[1]:+.3f}]" if d.boot else ""
    return (f"paired difference {d.est:+.3f} [{d.lo:+.3f}, {d.hi:+.3f}] over {d.k} training seeds x {d.n} episodes "
            f"(t over training seeds{boot}; training seeds carry {100 * (d.share or 0):.0f}% of its variance"
            f"{_fixed_note(d)})")


def seeds_note(d: Diff, bounds: list[float]) -> str:
    """'; about 5 training seeds would decide it, if ...' for a comparison over several training seeds whose interval
    still contains one of its claim's bounds (stats.seeds_to_decide, a projection); '' otherwise."""
    if d.k < 2 or d.within_var is None or all(not d.lo <= b <= d.hi for b in bounds):
        return ""
    k = seeds_to_decide(list(d.per_seed), d.within_var, bounds)
    need = f"about {k} training seeds would decide it" if k else "more than 50 training seeds would be needed"
    return f"; {need}, if its estimate and the spread of its {d.k} seeds held (a projection, not a result)"


def _undertrained(points: list[Point]) -> list[str]:
    return sorted({p.run or p.name for p in points if p.converged is False})


BOUNDS = {1.0: "ceiling", 0.0: "floor"}  # a score every episode of a comparison can share only at its bound


def _bound(points: list[Point]) -> str:
    """'ceiling' (or 'floor') when every episode of every setting compared, every training seed, scored 1.0 (0.0).

    A task every policy solves (MetaWorld's drawer-open from 10 demonstrations) gives +0.000 [+0.000, +0.000] for any
    pair: a rule reads that as "no better by the margin" or "as good", but the task has nothing left to separate. The
    verdict keeps its rule; the evidence and the cross-task table say so beside it."""
    scores = {v for p in points for run in (p.seeds or [p.scores]) for v in run.values()}
    return BOUNDS.get(scores.pop(), "") if len(points) > 1 and len(scores) == 1 else ""


def _finish(number: int, claim: str, rule: str, verdict: str, evidence: str, used: list[Point],
            compared: list[Point] | None = None) -> Finding:
    """The verdict, or 'undertrained' where a setting it rests on (`used`) is not shown converged; `compared` (default
    `used`): every setting the comparison read, for the ceiling note."""
    bound = _bound(used if compared is None else compared)
    if bound:
        evidence += (f"; every episode of every setting compared scored {'1.0' if bound == 'ceiling' else '0.0'}: at "
                     f"the score's {bound}, this task cannot separate them")
    late = _undertrained(used)
    if late:
        return Finding(number, claim, UNDERTRAINED, f"{evidence} (not judged: {', '.join(late)} not shown converged; "
                       "see 'Training: converged?')", rule, bound=bound)
    return Finding(number, claim, verdict, evidence, rule, bound=bound)


def _at_most(lo: float, hi: float, bound: float) -> str:
    """Claim 'difference <= bound': supported below it, contradicted above it."""
    return SUPPORTED if hi < bound else (CONTRADICTED if lo > bound else INCONCLUSIVE)


def _at_least(lo: float, hi: float, bound: float) -> str:
    """Claim 'difference >= bound': supported above it, contradicted below it."""
    return SUPPORTED if lo > bound else (CONTRADICTED if hi < bound else INCONCLUSIVE)


def _combine(verdicts: list[str]) -> str:
    """Several comparisons behind one claim: any contradicted -> contradicted; all supported -> supported."""
    if CONTRADICTED in verdicts:
        return CONTRADICTED
    return SUPPORTED if set(verdicts) == {SUPPORTED} else INCONCLUSIVE


def dp_point(points: list[Point], sampler: str, steps: int, schedule: str = "squaredcos_cap_v2") -> Point | None:
    """A cosine-beta DP setting, trailing spacing preferred over leading."""
    for variant in (f"{sampler}{steps}", f"{sampler}{steps}-leading"):
        for p in points:
            if p.policy == "diffusion" and p.variant == variant and (p.beta_schedule or schedule) == schedule:
                return p
    return None


def finding_1(points: list[Point], m: float) -> Finding:
    claim = "Accuracy does not rise in proportion to inference time"
    rule = (f"DP cosine DDPM-100 (fixed in advance: the study's own slow setting) minus the best of the learned "
            f"settings at least {SLOWER:g}x faster (best chosen inside each bootstrap resample): supported if the "
            f"interval lies below +{m}, contradicted if above; undertrained if the slow setting, or (unless "
            "supported) any faster one, was not shown converged.")
    timed = [p for p in points if p.latency_ms and p.policy not in ("random", "scripted") and (p.scores or p.seeds)]
    slow = dp_point(points, "ddpm", 100)
    if slow is None or not slow.latency_ms or not (slow.scores or slow.seeds):
        return Finding(1, claim, INCONCLUSIVE, "DP cosine DDPM-100 is not evaluated and timed", rule,
                       evaluated=False)
    fast = [p for p in timed if p.latency_ms * SLOWER <= slow.latency_ms]
    if not fast:
        return Finding(1, claim, INCONCLUSIVE, f"no setting is {SLOWER:g}x faster than {_fmt(slow)}", rule)
    d = paired_interval(slow, fast)
    best = max(fast, key=lambda p: p.score)
    evidence = (f"{_fmt(slow)} against the best of {len(fast)} settings >= {SLOWER:g}x faster ({_fmt(best)}): "
                f"{_fmt_diff(d)}{seeds_note(d, [m])}{_timing_note([slow, *fast])}")
    verdict = _at_most(d.lo, d.hi, m)
    evidence += _border_note(slow, timed, fast, verdict, m) + _without_fixed_note(slow, fast, d, verdict, m)
    # more training can only raise the faster settings' scores, which keeps "supported" supported: then only
    # the slow setting's convergence matters (an undertrained slow one could still rise above them)
    return _finish(1, claim, rule, verdict, evidence, [slow] if verdict == SUPPORTED else [slow, *fast],
                   [slow, *fast])


def _border_note(slow: Point, timed: list[Point], fast: list[Point], verdict: str, m: float) -> str:
    """The settings within BORDER of the 10x line, and what the paired comparison reads had they fallen on its
    other side (a timing fluctuation of that size moves them), "the same" where it agrees: a sensitivity statement,
    not a second rule."""
    border = [p for p in timed if p is not slow and abs(slow.latency_ms / p.latency_ms / SLOWER - 1) <= BORDER]
    if not border:
        return ""
    other = [p for p in timed if (p in fast) != (p in border) and p is not slow]
    names = ", ".join(f"{p.name} at {slow.latency_ms / p.latency_ms:.1f}x" for p in border)
    if not other:
        return f"; on the {SLOWER:g}x line (within {BORDER:.0%}): {names}; without them no setting is compared"
    d = paired_interval(slow, other)
    # the paired comparison alone: the convergence rule (undertrained) is not applied to it
    return (f"; on the {SLOWER:g}x line (within {BORDER:.0%}): {names}; counted on the other side, the comparison "
            f"would read {_would_read(d, verdict, m)} ({_fmt_diff(d)})")


def _would_read(d: Diff, verdict: str, m: float) -> str:
    """A sensitivity comparison's reading by finding 1's rule: "the same" where it agrees with the verdict."""
    alt = _at_most(d.lo, d.hi, m)
    return "the same" if alt == verdict else alt


def _without_fixed_note(slow: Point, fast: list[Point], d: Diff, verdict: str, m: float) -> str:
    """What the comparison reads with the single trained runs held fixed (`held_fixed`) left out of the faster
    settings, where the slow setting has several training seeds: such a run is paired with every seed of the slow
    one, so training-seed variance no longer cancels within a seed and the interval widens. A sensitivity statement,
    not a second rule: the verdict stays the rule's."""
    rest = [p for p in fast if not held_fixed(p)]
    if not d.fixed or not slow.seeds or not rest or len(rest) == len(fast):
        return ""
    alt = paired_interval(slow, rest)
    return (f"; without the {len(fast) - len(rest)} faster settings of one training seed (held fixed), the "
            f"comparison would read {_would_read(alt, verdict, m)} ({_fmt_diff(alt)})")


def _timing_note(compared: list[Point]) -> str:
    """Which of the compared settings' times were taken in interleaved rounds (a drifting machine shifts the study's
    separate timing blocks by tens of percent, enough to move a setting across the 10x line)."""
    sources = sorted({p.timed for p in compared if p.timed})
    n = sum(bool(p.timed) for p in compared)
    if not sources:
        return ""
    which = "every time" if n == len(compared) else f"{n} of {len(compared)} times (the others: the study's blocks)"
    return f"; {which} from {', '.join(sources)}"


def with_interleaved(points: list[Point], timing: dict[str, Any] | None) -> list[Point]:
    """The points with the medians of an interleaved timing (`latency-paired*.json`, benchmarks/paired_latency.py:
    settings timed in turn, round after round) in place of the study's own blocks, where it timed the setting: DP and
    flow by sampler ("ddpm100", "euler2"), another policy's default setting by its name ("bct"). `timing` must be in
    the points' inference mode (the caller picks the file by mode)."""
    if not timing:
        return points
    ms, source = timing["median_ms"], f"{timing['rounds']} interleaved rounds ({timing.get('file', 'latency-paired')})"
    keys = [interleaved_key(p.policy, p.variant) for p in points]
    return [replace(p, latency_ms=ms[k], timed=source) if k in ms else p for p, k in zip(points, keys, strict=True)]


def interleaved_key(policy: str, variant: str) -> str:
    """A setting's name in an interleaved timing's `median_ms`: DP and flow by sampler ("ddpm100"), another policy's
    default setting by the policy ("bct"); "" for a setting such a file does not time."""
    return variant if policy in ("diffusion", "flow") else policy if variant == "default" else ""


def shared_timing(rows: list[Any], timing: dict[str, Any] | None) -> list[str]:
    """Labels that take one interleaved median per setting: configurations of one policy that differ in no call
    (Diffusion Policy with linear betas beside cosine: the same network, sampler and step count; the schedule
    changes constants only). An interleaved timing times each setting once, on random weights, so they share it;
    the report says so rather than count both as timed in those rounds."""
    medians = (timing or {}).get("median_ms", {})
    labels: dict[tuple[str, str], dict[str, None]] = {}
    for r in rows:
        key = interleaved_key(r.policy, r.variant)
        if key in medians:
            labels.setdefault((r.policy, key), {})[r.label] = None
    out: dict[str, None] = {}
    for names in labels.values():
        if len(names) > 1:
            out.update(names)
    return list(out)


def finding_2(points: list[Point], m: float) -> Finding:
    claim = "10 denoising steps score as well as 100"
    rule = f"DDPM-10 minus DDPM-100 (cosine model): supported if the interval lies above -{m}, contradicted if below."
    p10, p100 = dp_point(points, "ddpm", 10), dp_point(points, "ddpm", 100)
    if p10 is None or p100 is None:
        return Finding(2, claim, INCONCLUSIVE, "DDPM-10 and DDPM-100 of the cosine model are not both evaluated", rule,
                       evaluated=False)
    d = paired_interval(p10, [p100])
    evidence = f"{_fmt(p10)} vs {_fmt(p100)}: {_fmt_diff(d)}{seeds_note(d, [-m])}"
    return _finish(2, claim, rule, _at_least(d.lo, d.hi, -m), evidence, [p10, p100])


def finding_3(points: list[Point], m: float, ratios: dict[str, float] | None = None) -> Finding:
    """`ratios`: DDIM-k / DDPM-k latency ratios timed in interleaved rounds ("ddim10/ddpm10": 0.99; see
    benchmarks/paired_latency.py), used instead of the ratio of the two settings' own timings where given."""
    claim = "DDIM changes neither accuracy nor inference time meaningfully"
    rule = (f"One pre-specified pair, DDIM-10 minus DDPM-10 (cosine model; the other step counts are shown but not "
            f"tested, so no multiplicity correction is needed): supported if the interval lies inside (-{m}, +{m}) and "
            "the latency ratio (timed in interleaved rounds where the study has them) in [0.8, 1.25]; contradicted if "
            "the interval lies wholly outside the margin or the ratio outside that range.")
    pairs = [(a, b) for k in range(1, 101) if (a := dp_point(points, "ddim", k)) and (b := dp_point(points, "ddpm", k))]
    tested = [(a, b) for a, b in pairs if a.variant == "ddim10"]
    if not tested:
        return Finding(3, claim, INCONCLUSIVE, "DDIM-10 and DDPM-10 of the cosine model are not both evaluated", rule,
                       evaluated=False)
    pairs = tested + [ab for ab in pairs if ab not in tested]  # the tested pair first, then the descriptive ones
    notes, verdicts = [], []
    for a, b in pairs:
        d = paired_interval(a, [b])
        lo, hi = d.lo, d.hi
        interleaved = f"{a.variant}/{b.variant}" in (ratios or {})
        ratio = (ratios[f"{a.variant}/{b.variant}"] if interleaved else
                 a.latency_ms / b.latency_ms if a.latency_ms and b.latency_ms else None)
        if lo > m or hi < -m or (ratio is not None and not 0.8 <= ratio <= 1.25):
            verdicts.append(CONTRADICTED)
        else:
            verdicts.append(SUPPORTED if -m < lo and hi < m else INCONCLUSIVE)
        time_note = f", time ratio {ratio:.2f}{' (interleaved timing)' if interleaved else ''}" if ratio else ""
        projection = seeds_note(d, [-m, m]) if not notes else ""  # the tested pair only
        notes.append(f"{a.name} vs {b.name}: {_fmt_diff(d)}{time_note}{projection}")
    notes[0] = "tested: " + notes[0] + (". Not tested (descriptive): " if len(notes) > 1 else "")
    return _finish(3, claim, rule, verdicts[0], notes[0] + "; ".join(notes[1:]), list(pairs[0]))


def finding_4(points: list[Point], m: float) -> Finding:
    claim = "ResNet-50 > BCT > CNN-MLP in score"
    rule = (f"ResNet-50 minus BCT and BCT minus CNN-MLP: supported if both intervals lie above +{m}, contradicted "
            f"if either lies below +{m} (not better by a meaningful amount).")
    by = {p.policy: p for p in points if p.variant == "default"}
    r, b, c = by.get("resnet50"), by.get("bct"), by.get("cnn_mlp")
    if not (r and b and c):
        return Finding(4, claim, INCONCLUSIVE, "ResNet-50, BCT and CNN-MLP are not all evaluated", rule,
                       evaluated=False)
    d1, d2 = paired_interval(r, [b]), paired_interval(b, [c])
    v1, v2 = _at_least(d1.lo, d1.hi, m), _at_least(d2.lo, d2.hi, m)
    # a verdict about miniatures is a verdict at their sizes (sized_label names them so), not about the study's nets
    miniature = any(re.search(r"\(\d+\.\d+ M", p.name) for p in (r, b, c))
    sizes = ("At these sizes, not the study's networks (ResNet-50 CNN 34.5 M ImageNet-initialised, BCT 24.0 M, "
             "CNN-MLP 1.37 M): " if miniature else "")
    evidence = (f"{sizes}{_fmt(r)}; {_fmt(b)}; {_fmt(c)}; ResNet-50 - BCT: {_fmt_diff(d1)}{seeds_note(d1, [m])}; "
                f"BCT - CNN-MLP: {_fmt_diff(d2)}{seeds_note(d2, [m])}")
    return _finish(4, claim, rule, _combine([v1, v2]), evidence, [r, b, c])


def finding_5(points: list[Point], m: float) -> Finding:
    claim = "BeT fails (scores no better than chance)"
    rule = f"BeT minus the random baseline: supported if the interval lies below +{m}, contradicted if above."
    by = {p.policy: p for p in points if p.variant == "default"}
    bet, rnd = by.get("bet"), by.get("random")
    if bet is None or rnd is None:
        return Finding(5, claim, INCONCLUSIVE, "BeT and the random baseline are not both evaluated", rule,
                       evaluated=False)
    d = paired_interval(bet, [rnd])
    evidence = f"{_fmt(bet)} vs {_fmt(rnd)}: {_fmt_diff(d)}{seeds_note(d, [m])}"
    return _finish(5, claim, rule, _at_most(d.lo, d.hi, m), evidence, [bet])


def judge(points: list[Point], margin: float = DEFAULT_MARGIN, ratios: dict[str, float] | None = None) -> list[Finding]:
    """The five findings; `ratios` as for finding_3."""
    return [finding_1(points, margin), finding_2(points, margin), finding_3(points, margin, ratios),
            finding_4(points, margin), finding_5(points, margin)]


def points_from_rows(rows: list, mode: str = "reference") -> list[Point]:
    return [Point(r.setting, r.policy, r.variant, r.score,
                  tuple(r.est("mean_score")["ci95"]), r.latency_ms(mode), r.beta_schedule, dict(r.scores),
                  getattr(r, "converged", None), r.label, [dict(sc) for sc in r.seed_scores], list(r.seed_ids),
                  None if r.seed_scores else r.train_seed, timed_at=getattr(r, "timed_at", ""))
            for r in rows]
