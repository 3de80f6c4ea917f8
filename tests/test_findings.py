"""The findings' verdicts on constructed per-seed evidence: every finding reaches all three outcomes."""

from __future__ import annotations

import numpy as np
import pytest

from bcbench.analysis.findings import (
    CONTRADICTED,
    INCONCLUSIVE,
    SUPPORTED,
    UNDERTRAINED,
    Point,
    judge,
    paired_interval,
)

N = 100
BASE = np.random.default_rng(0).uniform(0.2, 0.8, N)  # a policy's per-seed scores
Z = np.random.default_rng(1).standard_normal(N)
NOISY = 0.3 * (Z - Z.mean()) / Z.std()  # zero-mean noise: a paired interval of about +-0.06


def pt(name: str, policy: str, scores: np.ndarray, ms: float | None = 10.0, variant: str = "default",
       beta: str | None = None, converged: bool | None = None) -> Point:
    return Point(name, policy, variant, float(np.mean(scores)), (0.0, 1.0), ms, beta,
                 {100_000 + i: float(s) for i, s in enumerate(scores)}, converged)


def verdict(points: list[Point], number: int) -> str:
    return judge(points)[number - 1].verdict


def test_paired_interval_covers_a_known_difference_and_pairs_by_seed():
    a, b = pt("a", "x", BASE + 0.1 + NOISY), pt("b", "x", BASE)
    d = paired_interval(a, [b])
    est, lo, hi, n = d.est, d.lo, d.hi, d.n
    assert d.k == 1 and d.share is None and n == N and est == pytest.approx(0.1) and lo < 0.1 < hi and hi - lo < 0.2
    shifted = Point("c", "x", "default", 0, (0, 1), None, None, {s + 1: v for s, v in b.scores.items()})
    assert paired_interval(a, [shifted])[3] == N - 1  # only seeds both have count


# (scores of the claimed-better-or-equal side relative to the other) for the three outcomes
EQUAL, FAR, EDGE = 0.0, 0.3, 0.05


@pytest.mark.parametrize("shift, noise, expected", [(EQUAL, 0.0, SUPPORTED), (FAR, 0.0, CONTRADICTED),
                                                    (EDGE, NOISY, INCONCLUSIVE)])
def test_finding_1_slowest_against_the_best_faster(shift, noise, expected):
    fast = [pt("cnn", "cnn_mlp", BASE, ms=2.0), pt("bct", "bct", BASE - 0.2, ms=12.0)]
    slow = pt("dp100", "diffusion", BASE + shift + noise, ms=1000.0, variant="ddpm100")
    assert verdict([*fast, slow], 1) == expected


@pytest.mark.parametrize("slow_converged, fast_converged, shift, expected", [
    (True, False, EQUAL, SUPPORTED),  # more training of the faster ones could only confirm it
    (False, True, EQUAL, UNDERTRAINED),  # the slow one might still rise above them
    (True, False, FAR, UNDERTRAINED)])  # a faster one might still rise to it
def test_finding_1_waits_only_for_the_policies_that_could_change_it(slow_converged, fast_converged, shift,
                                                                    expected):
    fast = [pt("cnn", "cnn_mlp", BASE, ms=2.0, converged=True),
            pt("bct", "bct", BASE - 0.2, ms=12.0, converged=fast_converged)]
    slow = pt("dp100", "diffusion", BASE + shift, ms=1000.0, variant="ddpm100", converged=slow_converged)
    assert verdict([*fast, slow], 1) == expected


@pytest.mark.parametrize("shift, noise, expected", [(EQUAL, 0.0, SUPPORTED), (-FAR, 0.0, CONTRADICTED),
                                                    (-EDGE, NOISY, INCONCLUSIVE)])
def test_finding_2_ten_steps_against_a_hundred(shift, noise, expected):
    pts = [pt("dp10", "diffusion", BASE + shift + noise, 100.0, "ddpm10"),
           pt("dp100", "diffusion", BASE, 1000.0, "ddpm100")]
    assert verdict(pts, 2) == expected


@pytest.mark.parametrize("shift, noise, ms, expected", [(EQUAL, 0.0, 100.0, SUPPORTED),
                                                        (-FAR, 0.0, 100.0, CONTRADICTED),
                                                        (EQUAL, 0.0, 50.0, CONTRADICTED),
                                                        (EDGE, NOISY, 100.0, INCONCLUSIVE)])
def test_finding_3_ddim_against_ddpm(shift, noise, ms, expected):
    pts = [pt("ddim10", "diffusion", BASE + shift + noise, ms, "ddim10"),
           pt("ddpm10", "diffusion", BASE, 100.0, "ddpm10")]
    assert verdict(pts, 3) == expected


@pytest.mark.parametrize("r_minus_b, b_minus_c, noise, expected", [(FAR, FAR, 0.0, SUPPORTED),
                                                                   (FAR, EQUAL, 0.0, CONTRADICTED),
                                                                   (FAR, -FAR, 0.0, CONTRADICTED),
                                                                   (EDGE, FAR, NOISY, INCONCLUSIVE)])
def test_finding_4_ordering(r_minus_b, b_minus_c, noise, expected):
    c = BASE - 0.3
    b = c + b_minus_c
    pts = [pt("cnn", "cnn_mlp", c), pt("bct", "bct", b), pt("r50", "resnet50", b + r_minus_b + noise)]
    assert verdict(pts, 4) == expected


@pytest.mark.parametrize("shift, noise, expected", [(EQUAL, 0.0, SUPPORTED), (FAR, 0.0, CONTRADICTED),
                                                    (EDGE, NOISY, INCONCLUSIVE)])
def test_finding_5_bet_against_random(shift, noise, expected):
    rnd = BASE * 0.2
    assert verdict([pt("random", "random", rnd), pt("bet", "bet", rnd + shift + noise)], 5) == expected


@pytest.mark.parametrize("value, bound", [(1.0, "ceiling"), (0.0, "floor"), (0.5, "")])
def test_a_comparison_where_every_episode_scores_the_same_bound_says_the_task_cannot_separate(value, bound):
    """Drawer-open from 10 demonstrations: every policy 100/100, so finding 4 reads +0.000 [+0.000, +0.000] and its
    rule says "contradicted" (not better by the margin). The verdict keeps its rule; the evidence says the task has
    nothing to separate, and only where every episode of every setting compared sits at 1.0 (or 0.0)."""
    same = np.full(N, value)
    pts = [pt("cnn", "cnn_mlp", same), pt("bct", "bct", same), pt("r50", "resnet50", same)]
    f4 = judge(pts)[3]
    assert f4.verdict == CONTRADICTED and f4.bound == bound
    assert ("this task cannot separate them" in f4.evidence) == bool(bound)
    if bound:  # a single episode off the bound is evidence of a difference the task can show: no note
        one_off = same.copy()
        one_off[7] = 1.0 - value
        pts[0] = pt("cnn", "cnn_mlp", one_off)
        assert judge(pts)[3].bound == ""
    bet_vs_random = [pt("random", "random", np.zeros(N)), pt("bet", "bet", np.ones(N))]
    assert judge(bet_vs_random)[4].bound == ""  # 1.0 against 0.0 is a difference, not a bound


def test_missing_evidence_is_inconclusive_and_undertrained_is_not_judged():
    assert [f.verdict for f in judge([])] == [INCONCLUSIVE] * 5
    pts = [pt("random", "random", BASE * 0.2), pt("bet", "bet", BASE * 0.2, converged=False)]
    f5 = judge(pts)[4]
    assert f5.verdict == UNDERTRAINED and "not shown converged; see 'Training: converged?'" in f5.evidence
    assert all(f.rule for f in judge(pts))  # every finding states its rule


def test_margin_moves_the_verdict():
    pts = [pt("dp10", "diffusion", BASE - 0.1, 100.0, "ddpm10"), pt("dp100", "diffusion", BASE, 1000.0, "ddpm100")]
    assert judge(pts, margin=0.05)[1].verdict == CONTRADICTED
    assert judge(pts, margin=0.15)[1].verdict == SUPPORTED


def test_plateau_rule_on_learning_curves():
    from bcbench.analysis.curves import Curve, plateau

    def curve(scores):
        steps = [100 * (i + 1) for i in range(len(scores))]
        return Curve(samples=[64 * s for s in steps], steps=steps, score=scores, lo=scores, hi=scores)

    assert plateau(curve([0.1, 0.3, 0.5, 0.55, 0.6, 0.6, 0.61, 0.6]))[0]  # flat last quarter
    rising, why = plateau(curve([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8]))
    assert not rising and "still rising" in why
    assert not plateau(curve([0.5, 0.5, 0.5]))[0]  # too few points to show anything
    # rising through the third quarter, flat over the last: converged (the last quarter's mean is 0.077 above
    # the third quarter's, which is the rise *before* the plateau, not over it)
    assert plateau(curve([0.1, 0.3, 0.5, 0.55, 0.6, 0.62, 0.74, 0.76, 0.75, 0.76]))[0]
    # flat, then a late rise inside the last quarter: not converged
    assert not plateau(curve([0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.58, 0.66]))[0]


# ---------------------------------------------------------------- few-step policy against DP (issue 15's goal)
def fewstep_points(shift: float, flow_ms: float) -> list[Point]:
    return [pt("dp100", "diffusion", BASE, 1000.0, "ddpm100"), pt("ddim10", "diffusion", BASE, 100.0, "ddim10"),
            pt("ddim1", "diffusion", BASE * 0, 12.0, "ddim1"),
            pt("flow1", "flow", BASE + shift, flow_ms, "euler1"), pt("flow10", "flow", BASE + shift, 90.0, "euler10")]


@pytest.mark.parametrize("shift, flow_ms, goal", [(0.0, 15.0, "met at K = 1"), (0.0, 30.0, "not met"),
                                                  (-0.3, 15.0, "not met"), (0.2, 15.0, "met at K = 1")])
def test_fewstep_goal_needs_both_the_score_and_the_speed(shift, flow_ms, goal):
    from bcbench.analysis.fewstep import fewstep_lines

    lines = fewstep_lines(fewstep_points(shift, flow_ms), 0.05)
    assert f"**{goal}**" in lines[-2]
    row1 = next(line for line in lines if line.startswith("| 1 |"))
    assert f"{flow_ms / 100:.2f} |" in row1 and "| 0.000 [" in row1  # share of DDIM-10; DP DDIM-1 beside it
    assert ("better" if shift > 0.05 else "worse" if shift < -0.05 else "no worse") in row1


def test_fewstep_section_is_absent_without_flow_or_ddpm100():
    from bcbench.analysis.fewstep import fewstep_lines

    pts = fewstep_points(0.0, 15.0)
    assert fewstep_lines(pts[1:], 0.05) == [] and fewstep_lines(pts[:3], 0.05) == []


def test_a_flow_timed_in_another_sitting_than_ddim10_is_not_set_against_it():
    """A network timed again alone a day later (the VM's GEMM rate 97-121 GFLOP/s there, 175-184 the day before)
    must not make a speed-up: its share is withheld and the goal is not judged; in one sitting it is judged."""
    from dataclasses import replace
    from datetime import UTC, datetime

    from bcbench.analysis.fewstep import fewstep_lines

    day1 = (datetime(2026, 12, 6, 17, 30, tzinfo=UTC), datetime(2026, 12, 6, 17, 40, tzinfo=UTC))
    day2 = (datetime(2026, 12, 7, 18, 40, tzinfo=UTC), datetime(2026, 12, 7, 18, 50, tzinfo=UTC))
    at = {"ddim10": "2026-12-06T17:36:00+00:00", "flow1": "2026-12-07T18:43:00+00:00"}
    pts = [replace(p, timed_at=at.get(p.name, "")) for p in fewstep_points(0.0, 15.0)]
    lines = fewstep_lines(pts, 0.05, sittings=[day1, day2])
    row1 = next(line for line in lines if line.startswith("| 1 |"))
    assert row1.endswith("| 15.0 | - (another sitting) |")
    assert "**not judged (flow K = 1 and DP DDIM-10 timed in different sittings)**" in lines[-2]
    assert "**met at K = 1**" in fewstep_lines(pts, 0.05, sittings=[(day1[0], day2[1])])[-2]  # one sitting
    assert "**met at K = 1**" in fewstep_lines(pts, 0.05)[-2]  # no sittings known: as before
    worse = [replace(p, timed_at=at.get(p.name, "")) for p in fewstep_points(-0.3, 15.0)]
    assert "**not met**" in fewstep_lines(worse, 0.05, sittings=[day1, day2])[-2]  # its score fails anyway


def test_interleaved_timings_replace_the_study_blocks_where_given():
    """A study times settings in separate blocks minutes apart; a paired (interleaved) file corrects both the
    few-step latency share and finding 3's DDIM/DDPM time ratio, in the mode it was timed in only."""
    from bcbench.analysis.fewstep import fewstep_lines

    pts = fewstep_points(0.0, 30.0)  # by the study's blocks: 0.30 of DDIM-10, goal not met
    paired = {"mode": "fast", "rounds": 5, "threads": 2, "median_ms": {"euler1": 15.0, "ddim10": 100.0}}
    assert "**met at K = 1**" in fewstep_lines(pts, 0.05, paired=paired)[-2]
    assert "**not met**" in fewstep_lines(pts, 0.05, paired={**paired, "mode": "reference"})[-2]
    blocks = [pt("ddim10", "diffusion", BASE, 70.0, "ddim10"), pt("ddpm10", "diffusion", BASE, 100.0, "ddpm10")]
    assert judge(blocks)[2].verdict == CONTRADICTED  # a 0.70 time ratio from the blocks
    f3 = judge(blocks, ratios={"ddim10/ddpm10": 0.99})[2]
    assert f3.verdict == SUPPORTED and "0.99 (interleaved timing)" in f3.evidence


def test_finding_1_takes_interleaved_times_in_its_mode_and_says_so(tmp_path):
    """Which settings count as 10x faster than DDPM-100 rests on times that a drifting machine shifts between the
    study's separate blocks; an interleaved timing in the findings' mode replaces them where it timed the setting,
    the evidence names its source, and a study folder holds one such file per mode."""
    import json

    from bcbench.analysis.fewstep import load_paired
    from bcbench.analysis.findings import with_interleaved
    from bcbench.errors import BCBenchError

    dp100 = pt("dp100", "diffusion", BASE, 1000.0, "ddpm100")
    flow10, cnn = pt("flow10", "flow", BASE, 95.0, "euler10"), pt("cnn", "cnn_mlp", BASE - FAR, 2.0)
    by_blocks = judge([dp100, flow10, cnn])[0]
    assert by_blocks.verdict == SUPPORTED and "best of 2 settings" in by_blocks.evidence
    assert "interleaved" not in by_blocks.evidence
    timing = {"mode": "reference", "rounds": 10, "median_ms": {"ddpm100": 900.0, "euler10": 120.0},
              "file": "latency-paired.json"}
    points = with_interleaved([dp100, flow10, cnn], timing)
    assert [p.latency_ms for p in points] == [900.0, 120.0, 2.0]
    f1 = judge(points)[0]  # flow's 120 ms is no longer a tenth of DDPM-100's 900: only the weaker CNN is compared
    assert f1.verdict == CONTRADICTED and "best of 1 settings" in f1.evidence
    assert f1.evidence.endswith("; 1 of 2 times (the others: the study's blocks) from 10 interleaved rounds "
                                "(latency-paired.json)")
    assert with_interleaved([dp100], None) == [dp100]
    both = {**timing, "median_ms": {"ddpm100": 900.0, "cnn_mlp": 3.0}}
    every = judge(with_interleaved([dp100, flow10, cnn], both))[0]
    assert "; every time from 10 interleaved rounds (latency-paired.json)" in every.evidence  # by policy name
    for name, mode in (("latency-paired.json", "reference"), ("latency-paired-fast.json", "fast")):
        (tmp_path / name).write_text(json.dumps({**timing, "mode": mode}))
    loaded = load_paired(tmp_path)
    assert sorted(loaded) == ["fast", "reference"] and loaded["fast"]["file"] == "latency-paired-fast.json"
    (tmp_path / "latency-paired-again.json").write_text(json.dumps(timing))
    with pytest.raises(BCBenchError, match="a second interleaved timing in mode 'reference'"):
        load_paired(tmp_path)


def test_finding_1_shows_the_verdict_with_a_setting_on_the_10x_line_counted_the_other_way():
    """A setting within 10% of the 10x line is moved across it by a timing fluctuation of that size: the evidence
    names it and gives the verdict it would take counted on the other side, while the rule's verdict stands."""
    dp100 = pt("dp100", "diffusion", BASE, 1000.0, "ddpm100")
    cnn = pt("cnn", "cnn_mlp", BASE - FAR, 2.0)  # alone, DDPM-100 beats it: contradicted
    flow_out = pt("flow", "flow", BASE, 106.0, "euler10")
    flow_in = pt("flow", "flow", BASE, 96.0, "euler10")
    out = judge([dp100, cnn, flow_out])[0]  # 9.4x: not compared by the rule
    assert out.verdict == CONTRADICTED
    assert ("on the 10x line (within 10%): flow at 9.4x; counted on the other side, the comparison would read "
            "supported") in out.evidence
    inside = judge([dp100, cnn, flow_in])[0]  # 10.4x: compared, and as good as the slow setting
    assert inside.verdict == SUPPORTED
    assert "flow at 10.4x; counted on the other side, the comparison would read contradicted" in inside.evidence
    far = judge([dp100, cnn, pt("flow", "flow", BASE, 300.0, "euler10")])[0]  # 3.3x: not near the line
    assert far.verdict == CONTRADICTED and "10x line" not in far.evidence


def test_paired_latency_times_several_modes_in_one_run(tmp_path):
    """benchmarks/paired_latency.py with several --mode: one file per mode, named as the report looks them up, all
    stamped with one run_id (the control-loop table compares modes only within one run), each a loadable timing."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from bcbench.analysis.fewstep import load_paired, one_interleaved_run

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "paired_latency.py"
    proc = subprocess.run([sys.executable, str(script), "--config", "quick", "--steps", "1", "--flow-steps", "1",
                           "--rounds", "2", "--calls", "1", "--threads", "1", "--mode", "reference", "fast",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    files = sorted(p.name for p in tmp_path.glob("*.json"))
    assert files == ["latency-paired-fast.json", "latency-paired.json"]
    ref, fast = (json.loads((tmp_path / f).read_text()) for f in ("latency-paired.json", "latency-paired-fast.json"))
    assert ref["mode"] == "reference" and fast["mode"] == "fast" and ref["run_id"] == fast["run_id"]
    assert ref["interleaved_modes"] == ["reference", "fast"]
    assert sorted(ref["median_ms"]) == ["ddim1", "ddpm1", "euler1"] and all(v > 0 for v in ref["median_ms"].values())
    assert [len(r) for r in ref["samples_ms"]["ddpm1"]] == [1, 1]  # 2 rounds x 1 call
    assert sorted(one_interleaved_run(load_paired(tmp_path))) == ["fast", "reference"]


def test_finding_1_compares_the_fixed_slow_setting_not_the_slowest():
    """DP cosine DDPM-100 is fixed in advance: an even slower setting (DP linear DDIM-100) does not replace it."""
    fast = [pt("cnn", "cnn_mlp", BASE, ms=2.0)]
    dp100 = pt("dp100", "diffusion", BASE, ms=1000.0, variant="ddpm100")
    linear = pt("lin100", "diffusion", BASE - FAR, ms=2000.0, variant="ddim100", beta="linear")
    finding = judge([*fast, dp100, linear])[0]
    assert finding.verdict == SUPPORTED and finding.evidence.startswith("dp100 ")


def test_finding_3_tests_one_prespecified_pair():
    """Only DDIM-10 against DDPM-10 decides; another step count is shown, not tested."""
    pts = [pt("ddim10", "diffusion", BASE, 100.0, "ddim10"), pt("ddpm10", "diffusion", BASE, 100.0, "ddpm10"),
           pt("ddim2", "diffusion", BASE - FAR, 20.0, "ddim2"), pt("ddpm2", "diffusion", BASE, 20.0, "ddpm2")]
    finding = judge(pts)[2]
    assert finding.verdict == SUPPORTED and finding.evidence.startswith("tested: ddim10 vs ddpm10")
    assert "Not tested (descriptive): ddim2 vs ddpm2" in finding.evidence


def test_wilson_interval_of_a_share():
    from bcbench.stats import fmt_share, wilson

    lo, hi = wilson(0, 100)
    assert lo == 0.0 and 0.03 < hi < 0.04  # 0%: not [0, 0]
    assert wilson(50, 100) == pytest.approx((0.4038, 0.5962), abs=1e-4)
    assert fmt_share({"value": 0.22}, 100) == "22.0% [15.0, 31.1]"


def test_recovered_share_of_naives_loss_pairs_by_seed():
    """(other - naive) / (sync - naive) over shared seeds: 0 for naive itself, 1 for sync, 0.5 half-way; its
    interval covers the truth and narrows with more seeds; no loss, no share."""
    from bcbench.stats import recovered_share

    rng = np.random.default_rng(1)
    sync = {s: float(v) for s, v in enumerate(rng.uniform(0.6, 1.0, 400))}
    naive = {s: v - 0.4 for s, v in sync.items()}
    half = {s: v - 0.2 + float(rng.normal(0, 0.1)) for s, v in sync.items()}
    assert recovered_share(sync, naive, naive)[0] == 0.0 and recovered_share(sync, naive, sync)[0] == 1.0
    est, lo, hi, n = recovered_share(sync, naive, {**half, 9999: 5.0})  # an unshared seed is left out
    assert n == 400 and lo < 0.5 < hi and abs(est - 0.5) < 0.03 and hi - lo < 0.1
    few = recovered_share({k: sync[k] for k in range(40)}, naive, half)
    assert few[3] == 40 and few[2] - few[1] > hi - lo
    assert np.isnan(recovered_share(sync, sync, half)[0])


def test_study_machines_name_one_cpu_once_across_records_with_and_without_cpu_id(tmp_path):
    """An early training session recorded its CPU without cpu_id; later records of the same machine have it. The
    study's machine list names that CPU once, and a different CPU still appears."""
    from bcbench.analysis.results import study_machines
    from bcbench.utils.io import write_json

    xeon = {"cpu_model": "Xeon", "cpu_flags": ["avx2", "avx512f"]}
    write_json(tmp_path / "runs" / "a" / "train_summary.json", {"segments": [xeon, {**xeon, "cpu_id": "fam 6"}]})
    write_json(tmp_path / "runs" / "a" / "eval-x.json", {"hardware": {**xeon, "cpu_id": "fam 6"}})
    write_json(tmp_path / "runs" / "b" / "eval-y.json", {"hardware": {"cpu_model": "EPYC", "cpu_flags": ["avx2"]}})
    assert study_machines(tmp_path) == ["EPYC (avx2)", "Xeon [fam 6] (avx2, avx512f)"]


def test_an_undecided_comparison_over_seeds_says_how_many_seeds_would_decide_it():
    from bcbench.analysis.findings import Diff, seeds_note

    d = Diff(0.017, -0.106, 0.140, 100, 3, 0.5, (), (-0.04, 0.07), (0.017 - 0.05, 0.017, 0.017 + 0.05), 1e-8)
    assert seeds_note(d, [-0.05]) == ("; about 5 training seeds would decide it, if its estimate and the spread of its "
                                      "3 seeds held (a projection, not a result)")
    assert seeds_note(d._replace(lo=-0.04), [-0.05]) == ""  # decided already
    assert seeds_note(Diff(0.017, -0.106, 0.140, 100), [-0.05]) == ""  # one training seed: nothing to project


def test_finding_1_says_what_it_reads_without_the_faster_settings_of_one_training_seed():
    """A single trained run among the faster settings is paired with every seed of the slow one, so the seed-to-seed
    spread of the slow setting no longer cancels: the interval widens and the rule's verdict can change. The evidence
    then says what the comparison reads without such runs (a sensitivity statement; the verdict stays the rule's)."""
    rng = np.random.default_rng(3)
    level = [0.88, 0.78, 0.89]  # the slow setting's training seeds differ by 0.1, as Diffusion Policy's do
    slow_seeds = [{100_000 + i: float(v) for i, v in enumerate(np.clip(lv + rng.normal(0, .05, 100), 0, 1))}
                  for lv in level]
    fast_seeds = [{k: v - 0.005 for k, v in s.items()} for s in slow_seeds]  # the same model 10x faster, per seed

    def multi(name: str, variant: str, seeds: list[dict[int, float]], ms: float) -> Point:
        pooled = [v for s in seeds for v in s.values()]
        return Point(name, "diffusion", variant, float(np.mean(pooled)), (0.0, 1.0), ms, "squaredcos_cap_v2",
                     converged=True, run=name, seeds=seeds, seed_ids=[0, 1, 2])

    slow = multi("DP DDPM100", "ddpm100", slow_seeds, 600.0)
    fast = multi("DP DDPM5", "ddpm5", fast_seeds, 30.0)
    single = pt("DP linear DDPM5", "diffusion", np.full(100, 0.86), ms=30.0, variant="ddpm5", beta="linear",
                converged=True)
    single.train_seed = 0
    alone = judge([slow, fast])[0]
    assert alone.verdict == "supported" and "held fixed" not in alone.evidence
    both = judge([slow, fast, single])[0]
    assert both.verdict == "inconclusive"  # the single run's level against seed 1's 0.78 widens the interval
    assert "without the 1 faster settings of one training seed (held fixed), the comparison would read supported" in (
        both.evidence)


def test_a_learning_curve_reads_its_rollout_and_validation_lines_only(tmp_path):
    """load_curve skips the training-loss lines before parsing them (a report reads ~150 runs' logs); the rollout and
    validation lines it keeps are read as before, and a torn last line is still ignored."""
    import json

    from bcbench.analysis.curves import load_curve

    lines = [{"step": s, "samples": 64 * s, "loss": 0.5} for s in range(1, 5)]
    lines.insert(2, {"step": 2, "samples": 128, "eval_score": {"value": 0.25, "ci95": [0.1, 0.4]}, "eval_wall_s": 1.5})
    lines.append({"step": 4, "samples": 256, "val_loss": 0.125})
    (tmp_path / "metrics.jsonl").write_text("\n".join(map(json.dumps, lines)) + '\n{"step": 5, "val_loss": 0.')
    c = load_curve(tmp_path)
    assert (c.samples, c.steps, c.score, c.lo, c.hi) == ([128], [2], [0.25], [0.1], [0.4])
    assert (c.val_samples, c.val_loss) == ([256], [0.125])
    assert c.rollout_s == 1.5  # the study's time counts the rollouts from here
