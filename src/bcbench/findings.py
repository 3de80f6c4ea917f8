"""The study's five findings, each judged on this run's evidence: supported, not supported, inconclusive.

Rules (with 95% bootstrap intervals on mean scores; "significantly" = the intervals do not overlap):
1. Accuracy does not rise in proportion to inference time: among pairs of evaluated settings where one
   is at least 3x slower, supported if some slower one is not significantly better; not supported if every
   such slower setting is significantly better; inconclusive without such pairs.
2. 10 denoising steps score as well as 100: DDPM-10 vs DDPM-100 of the same model (cosine betas);
   supported if their intervals overlap, not supported if not, inconclusive if either is missing.
3. DDIM changes neither accuracy nor time meaningfully: DDIM-k vs DDPM-k for every k present in both;
   supported if every score interval overlaps and every latency ratio lies in [0.8, 1.25].
4. ResNet-50 > BCT > CNN-MLP in score: supported if both orderings are significant; not supported if either
   is significantly reversed; inconclusive otherwise.
5. BeT fails: supported if BeT is not significantly better than the random baseline (or scores < 0.05
   without a random baseline), not supported if it is significantly better.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

SUPPORTED, NOT_SUPPORTED, INCONCLUSIVE = "supported", "not supported", "inconclusive"


@dataclass
class Point:
    """What a finding needs of one evaluated setting."""

    name: str
    policy: str
    variant: str  # "default" or e.g. "ddpm10"
    score: float
    ci: tuple[float, float]
    latency_ms: float | None
    beta_schedule: str | None = None


@dataclass
class Finding:
    number: int
    claim: str
    verdict: str
    evidence: str


def _overlap(a: Point, b: Point) -> bool:
    return not (a.ci[1] < b.ci[0] or b.ci[1] < a.ci[0])


def _better(a: Point, b: Point) -> bool:
    """a significantly better than b."""
    return a.ci[0] > b.ci[1]


def _fmt(p: Point) -> str:
    lat = f", {p.latency_ms:.1f} ms" if p.latency_ms is not None else ""
    return f"{p.name} {p.score:.3f} [{p.ci[0]:.3f}, {p.ci[1]:.3f}]{lat}"


def _dp(points: list[Point], sampler: str, steps: int, schedule: str = "squaredcos_cap_v2") -> Point | None:
    for p in points:
        if p.policy == "diffusion" and p.variant == f"{sampler}{steps}" and (p.beta_schedule or schedule) == schedule:
            return p
    return None


def finding_1(points: list[Point]) -> Finding:
    claim = "Accuracy does not rise in proportion to inference time"
    timed = [p for p in points if p.latency_ms and p.policy not in ("random", "scripted")]
    pairs = [(s, f) for s in timed for f in timed if s.latency_ms >= 3 * f.latency_ms]
    if not pairs:
        return Finding(1, claim, INCONCLUSIVE, "no two timed learned settings differ by 3x in latency")
    counter = [(s, f) for s, f in pairs if not _better(s, f)]
    if counter:
        s, f = max(counter, key=lambda sf: sf[0].latency_ms / sf[1].latency_ms)
        ratio = s.latency_ms / f.latency_ms
        return Finding(1, claim, SUPPORTED, f"{_fmt(s)} is {ratio:.0f}x slower than {_fmt(f)} but not "
                       f"significantly better ({len(counter)} of {len(pairs)} such pairs)")
    return Finding(1, claim, NOT_SUPPORTED,
                   f"in all {len(pairs)} pairs the >=3x slower setting scores significantly higher")


def finding_2(points: list[Point]) -> Finding:
    claim = "10 denoising steps score as well as 100"
    p10, p100 = _dp(points, "ddpm", 10), _dp(points, "ddpm", 100)
    if p10 is None or p100 is None:
        return Finding(2, claim, INCONCLUSIVE, "DDPM-10 and DDPM-100 of the cosine model are not both evaluated")
    verdict = SUPPORTED if _overlap(p10, p100) else (NOT_SUPPORTED if _better(p100, p10) else SUPPORTED)
    return Finding(2, claim, verdict, f"{_fmt(p10)} vs {_fmt(p100)}")


def finding_3(points: list[Point]) -> Finding:
    claim = "DDIM changes neither accuracy nor inference time meaningfully"
    pairs = []
    for k in range(1, 101):
        a, b = _dp(points, "ddim", k), _dp(points, "ddpm", k)
        if a and b:
            pairs.append((a, b))
    if not pairs:
        return Finding(3, claim, INCONCLUSIVE, "no step count evaluated with both DDIM and DDPM (cosine model)")
    notes, ok = [], True
    for a, b in pairs:
        same_score = _overlap(a, b)
        ratio = a.latency_ms / b.latency_ms if a.latency_ms and b.latency_ms else None
        same_time = ratio is None or 0.8 <= ratio <= 1.25
        ok = ok and same_score and same_time
        notes.append(f"{_fmt(a)} vs {_fmt(b)}" + (f" (time ratio {ratio:.2f})" if ratio else ""))
    return Finding(3, claim, SUPPORTED if ok else NOT_SUPPORTED, "; ".join(notes))


def finding_4(points: list[Point]) -> Finding:
    claim = "ResNet-50 > BCT > CNN-MLP in score"
    by = {p.policy: p for p in points if p.variant == "default"}
    r, b, c = by.get("resnet50"), by.get("bct"), by.get("cnn_mlp")
    if not (r and b and c):
        return Finding(4, claim, INCONCLUSIVE, "ResNet-50, BCT and CNN-MLP are not all evaluated")
    evidence = f"{_fmt(r)}; {_fmt(b)}; {_fmt(c)}"
    if _better(r, b) and _better(b, c):
        return Finding(4, claim, SUPPORTED, evidence)
    if _better(b, r) or _better(c, b):
        return Finding(4, claim, NOT_SUPPORTED, evidence + " (an ordering is significantly reversed)")
    return Finding(4, claim, INCONCLUSIVE, evidence + " (intervals overlap)")


def finding_5(points: list[Point]) -> Finding:
    claim = "BeT fails (scores about zero)"
    by = {p.policy: p for p in points if p.variant == "default"}
    bet, rnd = by.get("bet"), by.get("random")
    if bet is None:
        return Finding(5, claim, INCONCLUSIVE, "BeT is not evaluated")
    if rnd is None:
        return Finding(5, claim, SUPPORTED if bet.score < 0.05 else NOT_SUPPORTED, _fmt(bet) + " (no random baseline)")
    verdict = NOT_SUPPORTED if _better(bet, rnd) else SUPPORTED
    return Finding(5, claim, verdict, f"{_fmt(bet)} vs {_fmt(rnd)}")


def judge(points: list[Point]) -> list[Finding]:
    return [f(points) for f in (finding_1, finding_2, finding_3, finding_4, finding_5)]


def points_from_rows(rows: list[Any], mode: str = "reference") -> list[Point]:
    return [Point(r.label + ("" if r.variant == "default" else f" {r.variant.upper()}"), r.policy, r.variant, r.score,
                  tuple(r.est("mean_score")["ci95"]), r.latency_ms(mode), r.beta_schedule) for r in rows]
