"""A confirm study's report over several training seeds: one row per setting, a two-level interval, each seed's
score beside it, findings paired within training seeds, the 2x check matched to its own seed."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from bcbench.analysis.findings import Point, paired_interval
from bcbench.analysis.report import write_report
from bcbench.analysis.results import load_rows
from bcbench.analysis.seeds import merge_training_seeds
from bcbench.utils.io import write_json

EPISODES = 100


def _eval(policy: str, label: str, scores: np.ndarray, seed: int | None, run: str, start: int = 100_000) -> dict:
    est = {"value": float(scores.mean()), "ci95": [float(scores.mean()) - 0.05, float(scores.mean()) + 0.05]}
    share = {"value": float((scores > 0.5).mean()), "ci95": [0, 1]}
    pol = {"name": policy, "parameters": 1000, "config": {"seed": seed}}
    if seed is not None:
        pol["run_dir"] = f"/x/{run}"
    return {"type": "evaluation", "policy": pol, "study": {"label": label, "run_dir": f"/x/{run}"},
            "episodes": [{"seed": start + i, "score": float(s)} for i, s in enumerate(scores)],
            "summary": {"n": len(scores), "mean_score": est, "share_above_0.5": share, "share_above_0.9": share,
                        "success_rate": share}, "hardware": {"cpu_model": "test cpu", "torch_threads": 2},
            "git_commit": "abc123"}


def _study(root: Path, seed_means: dict[str, list[float]]) -> Path:
    """Three learned policies (3 training seeds each, their means as given) and the random baseline."""
    rng = np.random.default_rng(0)
    base = rng.uniform(-0.15, 0.15, EPISODES)  # episode difficulty, shared by every setting (what pairing removes)
    base -= base.mean()
    policies = {"ResNet-50": "resnet50", "BCT": "bct", "CNN-MLP": "cnn_mlp"}
    for label, means in seed_means.items():
        for s, m in enumerate(means):
            scores = np.clip(m + base + rng.normal(0, 0.02, EPISODES), 0, 1)
            write_json(root / "runs" / f"{label}-s{s}" / "eval-default.json",
                       _eval(policies[label], label, scores, s, f"{label}-s{s}"))
    write_json(root / "runs" / "random" / "eval-default.json",
               _eval("random", "random", np.clip(0.2 + base, 0, 1), None, "random"))
    return root


def test_settings_merge_over_training_seeds_with_a_two_level_interval(tmp_path):
    _study(tmp_path, {"ResNet-50": [0.30, 0.50, 0.70], "BCT": [0.49, 0.50, 0.51], "CNN-MLP": [0.2, 0.2, 0.2]})
    rows = load_rows(tmp_path)
    assert len(rows) == 10 and sorted(r.train_seed for r in rows if r.policy == "bct") == [0, 1, 2]
    merged = {r.label: r for r in merge_training_seeds(rows)}
    assert len(merged) == 4 and merged["random"].seed_scores == []  # a baseline stays as it is
    wide, narrow = merged["ResNet-50"], merged["BCT"]
    assert wide.seed_ids == [0, 1, 2] and wide.summary["n"] == 3 * EPISODES
    assert wide.score == pytest.approx(0.5, abs=0.01)
    assert wide.summary["per_seed"] == pytest.approx([0.3, 0.5, 0.7], abs=0.01)
    (lo, hi), (nlo, nhi) = wide.est("mean_score")["ci95"], narrow.est("mean_score")["ci95"]
    # seeds far apart: the interval spans most of them and training seeds carry the variance; seeds alike: narrow
    assert hi - lo > 0.2 and wide.summary["training_seed_share"] > 0.9
    assert nhi - nlo < 0.1 and narrow.summary["training_seed_share"] < 0.9


def test_a_labels_latency_is_its_newest_timing_of_any_seed(tmp_path):
    """A study times one training seed per label, its lowest; a restored study whose seed 0 weights stayed behind
    times seed 1 in a later sitting (scripts/study_stages.py --any-seed --again): the merged setting, and so the
    table, Figure 5, the findings and the across-tasks cell, reads the newest timing; equal times, the lowest seed."""
    from bcbench.analysis.across_cells import latency_cell
    from bcbench.analysis.findings import points_from_rows

    _study(tmp_path, {"ResNet-50": [0.55, 0.60, 0.65], "BCT": [0.40, 0.45, 0.50], "CNN-MLP": [0.2, 0.2, 0.2]})

    def timed(seed: int, ms: float, created: str) -> None:
        write_json(tmp_path / "runs" / f"ResNet-50-s{seed}" / "latency-default.json",
                   {"type": "latency", "created": created, "modes": {"reference": {"median_ms": ms}},
                    "node": f"vm{seed}"})

    def merged() -> dict:
        return {r.label: r for r in merge_training_seeds(load_rows(tmp_path))}

    timed(1, 12.5, "2026-12-07T06:00:00+00:00")
    timed(2, 99.0, "2026-12-07T06:00:00+00:00")  # as new as seed 1's: the lower seed wins
    resnet, bct = merged()["ResNet-50"], merged()["BCT"]
    assert resnet.seed_ids == [0, 1, 2] and resnet.latency_ms() == 12.5 and resnet.timed_on == "vm1"
    assert latency_cell(resnet) == "12.5 ms (reference)" and latency_cell(bct) == "not timed"
    assert {p.run: p.latency_ms for p in points_from_rows(merged().values())}["ResNet-50"] == 12.5
    # and its time with it (the few-step section compares sittings): seed 1's, not seed 0's untimed empty one
    assert {p.run: p.timed_at for p in points_from_rows(merged().values())}["ResNet-50"] == "2026-12-07T06:00:00+00:00"
    timed(0, 30.0, "2026-12-07T01:00:00+00:00")  # seed 0's older sitting: seed 1's newer timing stays
    assert merged()["ResNet-50"].latency_ms() == 12.5
    timed(0, 30.0, "2026-12-07T07:00:00+00:00")
    assert merged()["ResNet-50"].latency_ms() == 30.0 and merged()["ResNet-50"].timed_on == "vm0"


def test_paired_findings_resample_training_seeds(tmp_path):
    # per-seed differences 0.05, 0.15, 0.25: the mean is 0.15 and training seeds make most of its spread
    _study(tmp_path, {"ResNet-50": [0.55, 0.60, 0.65], "BCT": [0.50, 0.45, 0.40], "CNN-MLP": [0.2, 0.2, 0.2]})
    pts = {r.label: Point(r.label, r.policy, r.variant, r.score, tuple(r.est("mean_score")["ci95"]), None, None,
                          dict(r.scores), None, r.label, [dict(s) for s in r.seed_scores], list(r.seed_ids))
           for r in merge_training_seeds(load_rows(tmp_path))}
    d = paired_interval(pts["ResNet-50"], [pts["BCT"]])
    assert d.k == 3 and d.n == EPISODES and d.est == pytest.approx(0.15, abs=0.01) and d.lo < 0.15 < d.hi
    one = paired_interval(Point("a", "x", "default", 0, (0, 1), None, None, pts["ResNet-50"].seeds[0]),
                          [Point("b", "x", "default", 0, (0, 1), None, None, pts["BCT"].seeds[0])])
    assert one.k == 1 and (d.hi - d.lo) > 3 * (one.hi - one.lo)  # one seed's interval hides the seed spread
    assert d.share > 0.9
    vs_baseline = paired_interval(pts["BCT"], [pts["random"]])  # a baseline pairs with every training seed
    assert vs_baseline.k == 3 and vs_baseline.est == pytest.approx(0.25, abs=0.01)


def test_a_single_trained_run_against_several_seeds_is_said_to_be_held_fixed(tmp_path):
    """Mid-study, one seed of a policy meets three of another: its one seed is paired with each of theirs, and the
    evidence says its seed-to-seed variance is not in the interval (a baseline, which has no training, is not)."""
    from bcbench.analysis.findings import _fmt_diff, points_from_rows

    _study(tmp_path, {"ResNet-50": [0.55, 0.60, 0.65], "BCT": [0.45], "CNN-MLP": [0.2, 0.2, 0.2]})
    pts = {p.run: p for p in points_from_rows(merge_training_seeds(load_rows(tmp_path)))}
    assert pts["BCT"].train_seed == 0 and pts["ResNet-50"].train_seed is None and pts["random"].train_seed is None
    d = paired_interval(pts["ResNet-50"], [pts["BCT"]])
    assert d.k == 3 and d.fixed == ("BCT (s0)",)
    assert "BCT (s0) has one training seed, held fixed: its seed-to-seed variance is not in the interval" in (
        _fmt_diff(d))
    assert paired_interval(pts["ResNet-50"], [pts["random"]]).fixed == ()
    md = Path(write_report(tmp_path)["markdown"]).read_text()
    assert "BCT (s0) has one training seed, held fixed" in md  # finding 4's evidence

def test_report_shows_each_seed_and_says_how_it_was_computed(tmp_path):
    _study(tmp_path, {"ResNet-50": [0.55, 0.60, 0.65], "BCT": [0.40, 0.45, 0.50], "CNN-MLP": [0.2, 0.2, 0.2]})
    md = Path(write_report(tmp_path)["markdown"]).read_text()
    assert "100 episodes each (seeds 100000-100099), 3 training seeds per trained setting" in md
    assert "| per training seed |" in md and re.search(r"s0 0\.5[45]\d, s1 0\.(59|60)\d, s2 0\.6[45]\d", md)
    table = md.split("## Results")[1].split("## Training")[0]
    assert table.count("| ResNet-50 |") == 1  # one row per setting, not one per seed
    assert "over 3 training seeds x 100 episodes (t over training seeds; two-level bootstrap [" in md  # finding 4
    how = md.split("## How to read the numbers")[1]
    assert "t interval over the training seeds' means" in how and "two-level bootstrap" in how
    assert re.search(r"\(training seeds: \d+% of variance; two-level bootstrap \[0\.\d{3}, 0\.\d{3}\]\)", table)


def test_the_double_is_compared_with_its_own_seed(tmp_path):
    """The 2x check (seed 0) is paired with seed 0 of the preset, not with whichever seed was read last."""
    from bcbench.analysis.convergence import doubling_checks

    _study(tmp_path, {"ResNet-50": [0.60, 0.60, 0.20], "BCT": [0.4] * 3, "CNN-MLP": [0.2] * 3})
    rows = load_rows(tmp_path)
    for r in rows:
        r.run_label = r.label
    double = next(r for r in rows if r.label == "ResNet-50" and r.train_seed == 0)
    twice = type(double)(**{**double.__dict__, "key": "2x:default", "label": "ResNet-50 2x", "run_label": "2x",
                            "doubles": "ResNet-50"})
    (check,) = doubling_checks([*rows, twice], 0.05)
    assert check.est == pytest.approx(0.0) and check.verdict == "converged"  # against seed 2 it would be +0.4


def test_a_confirm_study_checks_convergence_on_validation_only(tmp_path):
    """The 2x run and the seed it doubles are evaluated on validation episodes (check stage); the 2x run is not a
    setting of the confirm study: no test-seed evaluation, no timing."""
    import tomllib

    from bcbench.study.runner import StudyRunner
    from bcbench.study.spec import parse_spec

    spec = parse_spec(tomllib.loads(
        'run = [{ policy = "cnn_mlp", label = "base", steps = 20, seeds = [0, 1, 2] },'
        ' { policy = "cnn_mlp", label = "2x", steps = 40, doubles = "base" }]\n'
        '[study]\npurpose = "confirm"\nepisodes = 100\nseed_start = 100000\ncheck_episodes = 60\n'))
    plan = [(stage, run.label, run.seed) for stage, run, _ in StudyRunner(spec, tmp_path).stages()]
    assert [p for p in plan if p[0] == "eval"] == [("eval", "base", 0), ("eval", "base", 1), ("eval", "base", 2)]
    assert [p for p in plan if p[0] == "check"] == [("check", "base", 0), ("check", "2x", 0)]
    # timed once per setting, on its lowest training seed: an exact mode's time does not depend on the weights
    assert [p for p in plan if p[0] == "latency"] == [("latency", "base", 0)]
    with pytest.raises(Exception, match="check_episodes"):
        parse_spec(tomllib.loads('run = [{ policy = "cnn_mlp" }]\n[study]\ncheck_episodes = 20\n'))


def test_a_resized_check_runs_again_for_both_runs_and_nothing_else(tmp_path):
    """check_episodes on a doubling run sizes its check and that of the run it doubles (one set of episodes); a
    check file of another size is not done, so changing the count re-runs the check (issue 30: flow's check, first
    read on 100 episodes, re-read on 400), while the same file of the study's size stays done."""
    import tomllib

    from bcbench.study.runner import StudyRunner
    from bcbench.study.spec import parse_spec

    spec = parse_spec(tomllib.loads(
        'run = [{ policy = "cnn_mlp", label = "base", steps = 20, seeds = [0, 1] },'
        ' { policy = "cnn_mlp", label = "2x", steps = 40, doubles = "base", check_episodes = 80 }]\n'
        '[study]\npurpose = "confirm"\nepisodes = 100\nseed_start = 100000\ncheck_episodes = 60\n'))
    base0, base1, double = spec.runs
    assert [spec.check_size(r) for r in (base0, base1, double)] == [80, 60, 80]  # seed 1 has no doubling run
    runner = StudyRunner(spec, tmp_path)
    for run, n in ((base0, 60), (double, 80), (base1, 60)):
        rec = {"eval_config": {"episodes": n, "seed_start": 200_000}}
        write_json(runner.result_file("check", run, run.variants[0]), rec)
    assert [runner.is_done("check", r, r.variants[0]) for r in (base0, double, base1)] == [False, True, True]
    for bad in ('{ policy = "cnn_mlp", label = "base", steps = 20, check_episodes = 80 }',
                '{ policy = "cnn_mlp", label = "2x", steps = 40, doubles = "base", check_episodes = 20 }'):
        with pytest.raises(Exception, match="check_episodes goes on a doubling run"):
            parse_spec(tomllib.loads(f'run = [{{ policy = "cnn_mlp", label = "base", steps = 20 }}, {bad}]\n'
                                     '[study]\npurpose = "confirm"\nepisodes = 100\nseed_start = 100000\n'))


def test_report_reads_the_checks_from_validation_files(tmp_path):
    _study(tmp_path, {"ResNet-50": [0.55, 0.60, 0.65], "BCT": [0.40, 0.45, 0.50], "CNN-MLP": [0.2, 0.2, 0.2]})
    write_json(tmp_path / "spec.json", {"purpose": "confirm", "margin": 0.05})
    rng = np.random.default_rng(1)
    val = np.clip(0.5 + rng.uniform(-0.2, 0.2, 60), 0, 1)
    for run, label, doubles in (("BCT-s0", "BCT", None), ("BCT-2x", "BCT 2x", "BCT")):
        rec = _eval("bct", label, val, 0, run, start=200_000)
        rec["study"].update({"check": True, **({"doubles": doubles} if doubles else {})})
        write_json(tmp_path / "runs" / run / "check-default.json", rec)
    md = Path(write_report(tmp_path)["markdown"]).read_text()
    assert "Compared on validation episodes (seeds 200000+)" in md
    check_row = next(line for line in md.splitlines() if line.startswith("| BCT | - |") and "verdict" not in line
                     and "| 60 |" in line)
    assert check_row.endswith("| +0.000 [+0.000, +0.000] | 60 | **converged** |")
    table = md.split("## Results")[1].split("## Training")[0]
    assert "BCT 2x" not in table and "| BCT |" in table  # the check is not a setting of the table


def test_convergence_lines_name_the_training_seed_only_where_a_label_has_several(tmp_path):
    import dataclasses

    from bcbench.analysis.report import convergence_lines

    _study(tmp_path, {"ResNet-50": [0.55, 0.60, 0.65], "BCT": [0.40], "CNN-MLP": [0.2, 0.2]})
    rows = [dataclasses.replace(r, converged=True, convergence="flat") if r.train_seed is not None else r
            for r in load_rows(tmp_path)]
    lines = convergence_lines(rows)
    assert len(lines) == 6  # one per trained run; the baseline has none
    assert sum(line.startswith("- ResNet-50 (training seed ") for line in lines) == 3
    assert sum(line.startswith("- CNN-MLP (training seed ") for line in lines) == 2
    assert any(line.startswith("- BCT: converged") for line in lines)  # its only seed: not named


def test_the_lead_names_the_machine_of_every_training_seed():
    """Seeds of one setting evaluated on different machines: the lead line names each machine with its runs,
    not the first seed's machine for the merged setting."""
    from bcbench.analysis.provenance import hardware_line
    from bcbench.analysis.results import Row

    def row(seed, cpu, variant):
        return Row(key=f"dp-s{seed}:{variant}", label="DP", policy="diffusion", preset="cpu", variant=variant,
                   sampler="ddim", steps=10, spacing=None, beta_schedule=None, params=1, summary={},
                   hardware={"cpu_model": cpu, "cpu_flags": ["avx2"], "torch_threads": 2}, train_seed=seed)

    runs = [row(0, "AMD EPYC", "ddim10"), row(0, "AMD EPYC", "ddim1"), row(1, "Xeon", "ddim10"),
            row(1, "Xeon", "ddim1")]
    assert hardware_line(runs) == ("Evaluated on several machines: AMD EPYC (avx2): seed 0 of DP with 2 threads; "
                                   "Xeon (avx2): seed 1 of DP with 2 threads.")
    assert hardware_line([*runs, row(2, "Xeon", "ddim10")]).endswith("Xeon (avx2): seeds 1 and 2 of DP with 2 threads.")
    # one CPU, two thread counts, one training seed: each label once with its count of settings, "1 thread"
    flow = [Row(key=f"f:{v}", label="Flow", policy="flow", preset="cpu", variant=v, sampler="euler", steps=1,
                spacing=None, beta_schedule=None, params=1, summary={}, train_seed=0,
                hardware={"cpu_model": "Xeon", "cpu_flags": ["avx2"], "torch_threads": 1})
            for v in ("euler1", "euler2")]
    dp = [row(0, "Xeon", "ddim10"), row(0, "Xeon", "ddim1")]
    assert hardware_line([*flow, *dp]) == ("Evaluated on Xeon (avx2): all 2 settings of Flow with 1 thread; "
                                           "all 2 settings of DP with 2 threads.")
    assert hardware_line([flow[0], *dp]) == ("Evaluated on Xeon (avx2): Flow euler1 with 1 thread; "
                                             "all 2 settings of DP with 2 threads.")
    one_seed = [r for r in runs if r.train_seed == 0]
    assert hardware_line(one_seed) == "Evaluated on AMD EPYC (avx2), 2 threads."
    assert hardware_line([one_seed[0], row(1, "AMD EPYC", "ddim10")]) == "Evaluated on AMD EPYC (avx2), 2 threads."



def test_the_lead_names_the_machine_that_timed_when_another_evaluated():
    """A study resumed on a new VM times there: same model name and family, other ISA flags (no avx512_bf16). The
    lead must not say 'evaluated and timed' on the machine that only evaluated."""
    from bcbench.analysis.provenance import hardware_line
    from bcbench.analysis.results import Row

    old = {"cpu_model": "Xeon", "cpu_id": "family 6 model 207", "cpu_flags": ["avx2", "avx512_bf16"],
           "torch_threads": 2}
    new = {**old, "cpu_flags": ["avx2"]}

    def row(variant, timed):
        return Row(key=f"dp:{variant}", label="DP", policy="diffusion", preset="cpu", variant=variant, sampler="ddim",
                   steps=10, spacing=None, beta_schedule=None, params=1, summary={}, hardware=old, train_seed=0,
                   latency={"fast": {"median_ms": 1.0}}, timed_hardware=timed)

    assert hardware_line([row("ddim10", old)]) == ("Evaluated and timed on Xeon [family 6 model 207] (avx2, "
                                                   "avx512_bf16), 2 threads.")
    assert hardware_line([row("ddim10", new), row("ddim1", new)]) == (
        "Evaluated on Xeon [family 6 model 207] (avx2, avx512_bf16), 2 threads. "
        "Timed on Xeon [family 6 model 207] (avx2), 2 threads.")


def test_a_carried_run_plays_the_part_the_studys_spec_gives_it(tmp_path):
    """A run carried from another study (same run key, so the same model) keeps that study's label in its files:
    the first round's 2x run is the second round's seed 0. Its role here comes from this study's spec.json (matched
    on policy, preset, seed and overrides), so it is the base its own 2x check is paired with."""
    from bcbench.analysis.convergence import doubling_checks
    from bcbench.analysis.results import load_check_rows

    rng = np.random.default_rng(2)
    val = np.clip(0.5 + rng.uniform(-0.2, 0.2, 60), 0, 1)
    runs = {"flow-s0-aaa": ("flow 2x (first round)", "flow", 40), "flow-s0-bbb": ("flow 2x", None, 80)}
    for run, (file_label, doubles, steps) in runs.items():
        rec = _eval("flow", file_label, val, 0, run, start=200_000)
        rec["study"].update({"check": True, **({"doubles": doubles} if doubles else {})})
        write_json(tmp_path / "runs" / run / "check-default.json", rec)
        write_json(tmp_path / "runs" / run / "run.json", {"policy": "flow", "preset": "cpu", "overrides": {
            "optim.max_steps": steps, "seed": 0}})
    assert doubling_checks(load_check_rows(tmp_path), 0.05) == []  # the files' own labels pair nothing
    write_json(tmp_path / "spec.json", {"runs": [
        {"policy": "flow", "config": "cpu", "seed": 0, "overrides": {"optim.max_steps": 40}, "label": "flow"},
        {"policy": "flow", "config": "cpu", "seed": 0, "overrides": {"optim.max_steps": 80}, "label": "flow 2x",
         "doubles": "flow"}]})
    (check,) = doubling_checks(load_check_rows(tmp_path), 0.05)
    assert check.run == "flow" and check.n == 60 and check.est == pytest.approx(0.0)


def test_a_trained_setting_with_one_seed_beside_several_counts_as_one(tmp_path):
    """A stage still running (BCT with one seed) beside settings with three: the lead says 1/3, not 3; a baseline is
    not a trained setting."""
    from bcbench.analysis.seeds import episodes_and_seeds

    _study(tmp_path, {"ResNet-50": [0.55, 0.60, 0.65], "BCT": [0.45], "CNN-MLP": [0.2, 0.2, 0.2]})
    assert episodes_and_seeds(merge_training_seeds(load_rows(tmp_path)))[2] == [3]  # no training record: not trained
    write_json(tmp_path / "runs" / "BCT-s0" / "train_summary.json", {"steps": 10})
    assert episodes_and_seeds(merge_training_seeds(load_rows(tmp_path)))[2] == [1, 3]


def test_the_realtime_section_names_a_sweep_on_another_machine_and_its_one_training_seed():
    """A study resumed on a new machine whose real-time stages ran there, on training seed 0 of a policy evaluated
    with three: the section says where the sweep ran and that its scores are one model's; a sweep on the machine
    that evaluated the rows, pooled over its seeds, needs neither sentence."""
    from bcbench.analysis.provenance import sweep_provenance
    from bcbench.analysis.results import Row

    def row(seed, cpu):
        return Row(key=f"bct-s{seed}:default", label="BCT", policy="bct", preset="cpu", variant="default",
                   sampler=None, steps=None, spacing=None, beta_schedule=None, params=1, summary={}, train_seed=seed,
                   hardware={"cpu_model": cpu, "cpu_flags": ["avx2"], "torch_threads": 1})

    def setting(cpu, seed, pooled=False):
        summary = {"training_seeds": [0, 1, 2]} if pooled else {}
        return {"hardware": {"cpu_model": cpu, "cpu_flags": ["avx2"], "torch_threads": 2}, "summary": summary,
                "policy": {"config": {"seed": seed}}, "episodes": []}

    rows = [row(s, "Xeon") for s in (0, 1, 2)]
    text = sweep_provenance({"BCT": {"realtime-sync": setting("EPYC", 0)},
                             "BCT + ensemble": {"realtime-sync": setting("EPYC", 0)}}, rows)
    assert text.startswith("Swept on EPYC (avx2), 2 threads (BCT), a machine that evaluated none of the rows "
                           "above (Xeon (avx2)):")
    assert "Swept on training seed 0 only (of the 3 evaluated): BCT; those sweeps' scores are that model's" in text
    assert sweep_provenance({"BCT": {"realtime-sync": setting("Xeon", 0, pooled=True)}}, rows) == ""
    assert sweep_provenance({"BCT": {"realtime-sync": setting("Xeon", 0)}}, rows[:1]) == ""  # one seed, one machine
    # a sweep is the longest label's it starts with: "BCT long" (one seed) is not "BCT" (three)
    long = Row(key="bct-long:default", label="BCT long", policy="bct", preset="cpu", variant="default", sampler=None,
               steps=None, spacing=None, beta_schedule=None, params=1, summary={}, train_seed=0,
               hardware={"cpu_model": "Xeon", "cpu_flags": ["avx2"], "torch_threads": 1})
    assert sweep_provenance({"BCT long + ensemble": {"realtime-sync": setting("Xeon", 0)}}, [*rows, long]) == ""


@pytest.mark.parametrize("k, m, sizes", [(3, 0, None), (3, 2, None), (1, 1, None), (4, 3, [100, 93, 100, 86])])
def test_the_two_level_bootstrap_draws_as_the_plain_double_loop_does(k, m, sizes):
    """The bulk means (stats._resampled_means) give the interval a loop over resamples and slots gives, to the bit,
    with unequal episode counts and with no alternative: committed reports were computed with the loop."""
    from bcbench import stats

    rng = np.random.default_rng(7)
    sizes = sizes or [100] * k
    draw = lambda: [{e: float(rng.random() > 0.3) * rng.random() for e in range(n)} for n in sizes]  # noqa: E731
    seeds, others = draw(), [draw() for _ in range(m)] or None

    def loop() -> list[float]:  # the pre-vectorized statistic, verbatim in effect
        r = np.random.default_rng(0)
        per_seed = stats._seed_arrays(seeds, others)
        draws, boot = r.integers(0, k, size=(2000, k)), []
        for b in range(2000):
            ma, mr = [], []
            for j in draws[b]:
                a, rest = per_seed[j]
                idx = r.integers(0, a.size, a.size)
                ma.append(a[idx].mean())
                mr.append(rest[:, idx].mean(axis=1))
            boot.append(np.mean(ma) - (np.mean(mr, axis=0).max() if others else 0.0))
        alpha = (1.0 - 0.95) / 2.0  # as the module computes it (not exactly 0.025)
        return [float(q) for q in np.quantile(boot, [alpha, 1.0 - alpha])]

    assert stats.two_level_bootstrap(seeds, others, n_boot=2000)["ci95"] == loop()


@pytest.mark.parametrize("before", [0, 1, 2, 3], ids=lambda n: f"{n}-drawn-before")
def test_bounded_draws_read_what_one_call_at_a_time_reads(before):
    """stats.bounded_draws equals `rng.integers(0, b)` called once per bound, to the bit: with bounds whose words
    are often dropped (3 * 2**30: a quarter of them, more than its spare words), bounds of 1 (no word read), a
    half word held over from an earlier odd-sized draw (`before`), and the generator's next draw after it."""
    from bcbench import stats

    bounds = np.random.default_rng(before).choice([1, 2, 3, 93, 100, 3 * 2**30, 2**31 + 1, 2**32 - 1], size=3000)
    one, bulk = np.random.default_rng(11), np.random.default_rng(11)
    one.integers(0, 7, before), bulk.integers(0, 7, before)
    calls = np.array([one.integers(0, b) for b in bounds])
    got = stats.bounded_draws(bulk, bounds)
    assert got.dtype == np.int64 and (got == calls).all(), np.flatnonzero(got != calls)[:5]
    assert (np.asarray(bounds) == 3 * 2**30).sum() > 300  # enough drops to need more words than the spare 64
    assert not stats.bounded_draws(np.random.default_rng(0), np.ones(5, dtype=np.int64)).any()
    with pytest.raises(TypeError, match="PCG64"):
        stats.bounded_draws(np.random.Generator(np.random.MT19937(0)), bounds)
    with pytest.raises(ValueError, match="bounds"):
        stats.bounded_draws(np.random.default_rng(0), [0, 3])
