"""The report across tasks (`across.json`): one table of policy x task from each task's own study folder, the
findings' verdicts per task, the 80% goal and 3D Diffusion Policy's image-DP yardstick per difficulty group; and a
combined report, which reads studies of one task, refusing studies of several."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from bcbench.analysis.across import write_across_report
from bcbench.analysis.studies import study_spec
from bcbench.cli.main import main
from bcbench.errors import BCBenchError
from bcbench.utils.io import write_json


def _eval(policy: str, label: str, task: str, difficulty: str | None, successes: int, n: int = 50,
          seed: int = 0, variant: tuple[str, int] | None = None) -> dict:
    pol = {"name": policy, "parameters": 1000, "run_dir": "x", "config": {"seed": seed}}
    if variant:
        pol.update({"sampler": variant[0], "steps": variant[1]})
    episodes = [{"seed": 200_000 + i, "score": float(i < successes)} for i in range(n)]
    est = {"value": successes / n, "ci95": [0.0, 1.0]}
    return {"type": "evaluation", "policy": pol, "study": {"label": label}, "episodes": episodes,
            "eval_config": {"task": task}, "task": {"name": task, **({"difficulty": difficulty} if difficulty else {})},
            "summary": {"n": n, "mean_score": est, "share_above_0.5": est, "share_above_0.9": est,
                        "success_rate": est}, "hardware": {"cpu_model": "test cpu", "torch_threads": 2},
            "git_commit": "abc1234"}


def _study(folder: Path, task: str, difficulty: str | None, runs: dict[str, dict]) -> Path:
    write_json(folder / "spec.json", {"name": folder.name, "task": task, "purpose": "explore", "margin": 0.05})
    for name, ev in runs.items():
        write_json(folder / "runs" / name / f"eval-{name.split('@')[-1]}.json", ev)
    return folder


def _two_tasks(tmp_path: Path, drawer_difficulty: str | None = "easy") -> Path:
    d, p = "metaworld/drawer-open", "metaworld/peg-insert-side"
    _study(tmp_path / "drawer", d, drawer_difficulty, {
        "cnn@default": _eval("cnn_mlp", "CNN-MLP", d, drawer_difficulty, 50),
        **{f"dp{s}@ddim10": _eval("diffusion", "Diffusion Policy", d, drawer_difficulty, 40 + s, seed=s,
                                  variant=("ddim", 10)) for s in range(3)}})
    chance = {**_eval("random", "random", p, "medium", 0), "policy": {"name": "random", "parameters": 0}}
    _study(tmp_path / "peg", p, "medium", {"pcnn@default": _eval("cnn_mlp", "CNN-MLP", p, "medium", 20),
                                           "prandom@default": chance,
                                           "pdp0@ddim10": _eval("diffusion", "Diffusion Policy", p, "medium", 46,
                                                               variant=("ddim", 10))})
    out = tmp_path / "across"
    write_json(out / "across.json", {"tasks": ["../drawer", "../peg"], "why": "Two tasks side by side."})
    return out


def test_the_table_reads_each_task_with_its_interval_seeds_and_yardstick(tmp_path):
    out = _two_tasks(tmp_path)
    md = Path(write_across_report(out)["markdown"]).read_text()
    assert ("across: 2 tasks (metaworld/drawer-open, metaworld/peg-insert-side), on episode seeds 200000-200049 "
            "(validation: they make choices; they are not reported scores)") in md
    assert "| policy | metaworld/drawer-open (easy) | metaworld/peg-insert-side (medium) |" in md
    # one training seed: Wilson over the 50 episodes (20/50 -> [27.6, 53.8]); three: t over the seeds' rates
    assert ("| CNN-MLP | 100.0% [92.9, 100.0], 1 training seed; not timed | 40.0% [27.6, 53.8], 1 training seed; "
            "not timed |") in md
    # three seeds at 40, 41, 42 of 50: mean 0.82; t_2 * 0.01 / sqrt(3) = 0.025 is narrower than the episodes allow,
    # so the half-width is theirs, 1.96 * sqrt(mean p(1-p)/50 / 3) = 0.062
    assert ("| Diffusion Policy DDIM10 | 82.0% [75.8, 88.2], 3 training seeds; not timed | 92.0% [81.2, 96.8], "
            "1 training seed; not timed |") in md
    assert "| random | - | 0.0% [0.0, 7.1], no training; not timed |" in md  # a baseline has no training seed
    assert "| 3D Diffusion Policy's image DP, 10 demos (its difficulty group's mean; published) | 83.6% | 31.1% |" in md
    assert ("**metaworld/drawer-open**: best CNN-MLP 100.0% [92.9, 100.0], 1 training seed: its whole interval is at "
            "or above 80% (on 1 training seed; the goal reads 3); image DP's best here (Diffusion Policy DDIM10, "
            "82.0%) trained on an unrecorded number of demonstrations: not comparable with 3D Diffusion Policy's "
            "image-DP 83.6% (the easy group's mean, 10 demonstrations)") in md
    assert ("**metaworld/peg-insert-side**: best Diffusion Policy DDIM10 92.0% [81.2, 96.8], 1 training seed: its "
            "whole interval is at or above 80%") in md
    assert "## Demonstrations" not in md  # across.json names no records
    unjudged = "inconclusive (not evaluated)"
    assert f"| 5. BeT fails (scores no better than chance) | {unjudged} | {unjudged} |" in md
    assert "[its report](../../drawer/report/report.md)" in md
    assert "result files at commit(s) abc1234" in md
    assert "<table>" in (out / "report" / "report.html").read_text()


def test_the_demonstrations_trained_on_come_from_the_run_or_its_stores_record(tmp_path):
    out = _two_tasks(tmp_path)
    records = tmp_path / "demos"
    write_json(records / "drawer-open.json", {"kept": 200, "attempted": 200, "scripted_success_rate": 1.0,
                                              "episode_length": {"min": 86, "max": 93}})
    for s in range(3):  # drawer's DP trained on 10 (its run.json); peg's on its store less the 10% held out
        write_json(tmp_path / "drawer" / "runs" / f"dp{s}@ddim10" / "run.json", {"data_split": {"demos": 10}})
    write_json(records / "peg-insert-side.json", {"kept": 200, "attempted": 228, "scripted_success_rate": 0.877,
                                                  "episode_length": {"min": 60, "max": 352}})
    write_json(tmp_path / "peg" / "runs" / "pdp0@ddim10" / "run.json", {"data_split": {"val_fraction": 0.1}})
    write_json(out / "across.json", {"tasks": ["../drawer", "../peg"], "demos": "../demos"})
    md = Path(write_across_report(out)["markdown"]).read_text()
    assert ("image DP's best here on 10 demonstrations (Diffusion Policy DDIM10, 82.0% [75.8, 88.2]) is not "
            "separated from 3D Diffusion Policy's image-DP 83.6% (the easy group's mean, 10 demonstrations); one task "
            "against a group's mean, under bcbench's protocol, not theirs") in md
    assert ("image DP's best here (Diffusion Policy DDIM10, 92.0%) trained on 180 demonstrations: not comparable "
            "with 3D Diffusion Policy's image-DP 31.1%") in md
    assert ("- metaworld/peg-insert-side: 200 demonstrations kept of 228 scripted episodes (expert success 87.7%), "
            "lengths 60-352 steps") in md


def test_a_record_without_its_difficulty_takes_the_stated_one_and_a_clash_is_refused(tmp_path):
    out = _two_tasks(tmp_path, drawer_difficulty=None)
    assert "| metaworld/drawer-open (-) |" in Path(write_across_report(out)["markdown"]).read_text()
    spec = json.loads((out / "across.json").read_text())
    write_json(out / "across.json", {**spec, "difficulty": {"metaworld/drawer-open": "easy"}})
    assert "| metaworld/drawer-open (easy) |" in Path(write_across_report(out)["markdown"]).read_text()
    write_json(out / "across.json", {**spec, "difficulty": {"metaworld/peg-insert-side": "hard"}})
    with pytest.raises(BCBenchError, match=r"peg-insert-side's records name difficulty medium, across.json hard"):
        write_across_report(out)


@pytest.mark.parametrize("spec, message", [
    ({"tasks": []}, "'tasks' must list the study folders"),
    ({"tasks": ["../nowhere"]}, "names nowhere, which is not a study or combined report folder"),
    ({"tasks": ["../drawer", "../drawer2"]}, "drawer and drawer2 are both on metaworld/drawer-open"),
    ({"tasks": ["../drawer"], "difficulty": {"metaworld/drawer-open": 1}}, "'difficulty' maps a task name"),
    ({"tasks": ["../drawer"], "demos": 3}, "'demos' names the folder of the demonstration records"),
    ({"tasks": ["../drawer"], "demos": "../bogus"}, "not a demonstration record (no attempted, scripted"),
    ({"tasks": ["../drawer"], "more_demos": {"metaworld/drawer-open": 3}}, "'more_demos' maps a task name"),
    ({"tasks": ["../drawer"], "more_demos": {"metaworld/door-open": "../drawer2"}},
     "'more_demos' names metaworld/door-open, which none of its 'tasks' folders is on"),
    ({"tasks": ["../drawer"], "more_demos": {"metaworld/drawer-open": "../bogus"}}, "which is not a study folder"),
    ({"tasks": ["../drawer"], "more_demos": {"metaworld/drawer-open": "../peg"}},
     "gives ../peg for metaworld/drawer-open, but that study ran metaworld/peg-insert-side"),
    ({"tasks": ["../drawer"], "larger_frame": {"metaworld/drawer-open": "../drawer2"}},
     "gives ../drawer2 for metaworld/drawer-open, but that study ran metaworld/drawer-open, not "
     "metaworld/drawer-open@SIZE"),
    ({"tasks": ["../drawer"], "more_demo": {"metaworld/drawer-open": "../drawer2"}},
     "unknown key(s) 'more_demo'; across.json takes demos, difficulty, larger_frame, more_demos, tasks, why"),
    ({"tasks": ["../drawer"], "larger_frame": {"metaworld/door-open": "../drawer2"}},
     "'larger_frame' names metaworld/door-open, which none of its 'tasks' folders is on"),
])
def test_bad_across_files_are_one_line_errors(tmp_path, spec, message, capsys):
    _two_tasks(tmp_path)
    _study(tmp_path / "drawer2", "metaworld/drawer-open", "easy",
           {"cnn2@default": _eval("cnn_mlp", "CNN-MLP", "metaworld/drawer-open", "easy", 50)})
    write_json(tmp_path / "bogus" / "drawer-open.json", {"kept": 200})
    write_json(tmp_path / "bad" / "across.json", spec)
    assert main(["report", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert main(["report", str(tmp_path / "bad"), "--export", str(tmp_path / "e")]) == 2
    assert "has no result files of its own" in capsys.readouterr().err


def test_a_combined_report_keeps_its_studies_task_and_refuses_two_tasks(tmp_path):
    out = _two_tasks(tmp_path)
    assert main(["report", str(out)]) == 0
    write_json(tmp_path / "one" / "combine.json", {"studies": ["../drawer", "../drawer2"]})
    _study(tmp_path / "drawer2", "metaworld/drawer-open", "easy",
           {"cnn2@default": _eval("cnn_mlp", "CNN-MLP 2", "metaworld/drawer-open", "easy", 49)})
    assert study_spec(tmp_path / "one")["task"] == "metaworld/drawer-open"  # not Push-T's by default
    write_json(tmp_path / "two" / "combine.json", {"studies": ["../drawer", "../peg"]})
    with pytest.raises(BCBenchError, match=r"differ in task .* needs one \(a report across tasks reads several"):
        study_spec(tmp_path / "two")


def test_each_tasks_figure_5_and_3_are_drawn_where_its_study_timed_and_stepped(tmp_path):
    out = _two_tasks(tmp_path)
    peg = tmp_path / "peg" / "runs"
    write_json(peg / "pdp0@ddim100" / "eval-ddim100.json",
               _eval("diffusion", "Diffusion Policy", "metaworld/peg-insert-side", "medium", 47, variant=("ddim", 100)))
    for run, variant, ms in (("pdp0@ddim10", "ddim10", 20.0), ("pdp0@ddim100", "ddim100", 200.0),
                             ("pcnn@default", "default", 2.0)):
        m = {"median_ms": ms, "p99_ms": ms * 1.2, "tail_ms": ms * 1.2, "tail_stat": "p99"}
        modes = {"reference": m, "fast": {**m, "median_ms": ms / 2}}
        write_json(peg / run / f"latency-{variant}.json", {"type": "latency", "git_commit": "abc1234", "modes": modes})
    md = Path(write_across_report(out)["markdown"]).read_text()
    for fig in ("fig5_metaworld-peg-insert-side.png", "fig3_metaworld-peg-insert-side.png"):
        assert (out / "report" / fig).stat().st_size > 1000 and f"]({fig})" in md
    assert "(no Figure 5: its study timed nothing; no Figure 3: fewer than two step counts" in md  # drawer's
    assert "92.0% [81.2, 96.8], 1 training seed; 10.0 ms (fast)" in md  # the fastest exact mode's median
    page = (out / "report" / "report.html").read_text()  # the figures embedded (a copied page keeps them)
    assert "<img alt='Figure 5, metaworld/peg-insert-side' style='max-width:100%' src='data:image/png;base64," in page
    assert page.count("src='data:image/png;base64,") == 2 and "src='fig" not in page


def test_a_setting_whose_size_moves_with_the_task_is_one_row_with_its_range(tmp_path):
    """DP's network is 5.34 M on drawer-open and 5.37 M on pick-place (the goal in its proprioception): one setting,
    so one row, named with both sizes; a row whose size is the same on every task keeps its plain name."""
    d, p = "metaworld/drawer-open", "metaworld/pick-place"

    def dp(task: str, difficulty: str, params: int, successes: int) -> dict:
        ev = _eval("diffusion", "Diffusion Policy", task, difficulty, successes, variant=("ddim", 10))
        ev["policy"].update(parameters=params, config={"seed": 0, "pred_horizon": 4, "encoder_width": 16})
        return ev

    def bct(task: str, difficulty: str) -> dict:
        ev = _eval("bct", "BCT", task, difficulty, 10)
        ev["policy"].update(parameters=1_120_000, config={"seed": 0, "pred_horizon": 4, "encoder_width": 16})
        return ev

    _study(tmp_path / "drawer", d, "easy", {"dp@ddim10": dp(d, "easy", 5_340_000, 50), "bct@default": bct(d, "easy")})
    _study(tmp_path / "pick", p, "hard", {"dp@ddim10": dp(p, "hard", 5_370_000, 6), "bct@default": bct(p, "hard")})
    out = tmp_path / "across"
    write_json(out / "across.json", {"tasks": ["../drawer", "../pick"], "why": "Sizes move with the task."})
    md = Path(write_across_report(out)["markdown"]).read_text()
    dp_rows = [line for line in md.splitlines() if line.startswith("| Diffusion Policy")]
    assert dp_rows == ["| Diffusion Policy, 1/4 width (5.34-5.37 M by task) DDIM10 | 100.0% [92.9, 100.0], 1 training "
                       "seed; not timed | 12.0% [5.6, 23.8], 1 training seed; not timed |"], dp_rows
    assert "| BCT, 1/4 width (1.12 M) | 20.0% [11.2, 33.0], 1 training seed; not timed | 20.0%" in md


def test_what_every_learned_row_shares_is_said_once_under_the_table(tmp_path):
    """The first table has to end in a laptop's first screen as tasks fill in: a part of the label every learned
    row shares ("10 demos") is said once under it, a part some rows lack stays in theirs, a comma inside a size's
    parentheses does not split it, and the baseline keeps its name."""
    d = "metaworld/drawer-open"
    labels = {"cnn_mlp": "CNN-MLP, 10 demos", "resnet50": "ResNet-50 CNN, 10 demos, 1/8 width (0.48 M, random init)",
              "bct": "BCT, 10 demos, horizons 4 / 3"}
    runs = {f"{k}@default": _eval(k, label, d, "easy", 10) for k, label in labels.items()}
    runs["dp@ddim10"] = _eval("diffusion", "Diffusion Policy, 10 demos", d, "easy", 10, variant=("ddim", 10))
    runs["rnd@default"] = {**_eval("random", "random, 10 demos", d, "easy", 0),
                           "policy": {"name": "random", "parameters": 0}}
    _study(tmp_path / "drawer", d, "easy", runs)
    out = tmp_path / "across"
    write_json(out / "across.json", {"tasks": ["../drawer"]})
    md = Path(write_across_report(out)["markdown"]).read_text()
    names = [line.split(" | ")[0][2:] for line in md.splitlines() if line.startswith("| ") and "%" in line]
    assert names == ["random, 10 demos", "CNN-MLP", "ResNet-50 CNN, 1/8 width (0.48 M, random init)",
                     "BCT, horizons 4 / 3", "Diffusion Policy DDIM10",
                     "3D Diffusion Policy's image DP, 10 demos (its difficulty group's mean; published)"], names
    assert ("training seeds; latency at batch 1 in the fastest exact mode timed (median; 'not timed' where the study "
            "timed nothing). Every learned setting: 10 demos.") in md
    page = (out / "report" / "report.html").read_text()
    assert page.index("<div class='grid'><table>") < page.index("Every learned setting: 10 demos.")
    # two settings that would read alike once the shared parts go (their parts in another order) keep them all
    runs["bct2@default"] = _eval("bct", "BCT, horizons 4 / 3, 10 demos", d, "easy", 10)
    _study(tmp_path / "drawer", d, "easy", runs)
    md = Path(write_across_report(out)["markdown"]).read_text()
    assert "| BCT, 10 demos, horizons 4 / 3 |" in md and "| BCT, horizons 4 / 3, 10 demos |" in md
    assert "Every learned setting" not in md


def test_a_task_under_the_goal_reads_its_twice_the_steps_check_and_a_stage_with_more_demonstrations(tmp_path):
    out = _two_tasks(tmp_path)  # drawer-open 100%, peg 92%: neither is under 80%, so neither gets a why
    p = "metaworld/pick-place"

    def dp(successes: int, label: str = "Diffusion Policy", **study: str) -> dict:
        ev = _eval("diffusion", label, p, "hard", successes, variant=("ddim", 10))
        ev["study"].update(study)
        return ev

    pick = _study(tmp_path / "pick", p, "hard", {"dp@ddim10": dp(6)})  # its test score: 12%
    write_json(pick / "runs" / "dp@ddim10" / "check-ddim10.json", dp(10))  # the check base, validation: 20%
    write_json(pick / "runs" / "dp@ddim10" / "run.json", {"data_split": {"demos": 10}})
    write_json(out / "across.json", {"tasks": ["../drawer", "../peg", "../pick"]})
    why = [x for x in Path(write_across_report(out)["markdown"]).read_text().splitlines() if x.startswith("- **")]
    assert why[-1] == ("- **metaworld/pick-place**: twice the steps: no twice-the-steps check yet; demonstration "
                       "count: no stage with more demonstrations yet."), why
    assert sum("drawer-open**: twice" in x or "peg-insert-side**: twice" in x for x in why) == 0

    # the confirm run's twice-the-steps check lands (12 of the same 50 validation episodes against its base's 10)
    # (its folder sorts after the base's: the twice-the-steps run's files must not stand in for the base's)
    write_json(pick / "runs" / "zz2x@ddim10" / "check-ddim10.json",
               dp(12, "Diffusion Policy, twice the steps", doubles="Diffusion Policy"))
    write_json(pick / "runs" / "zz2x@ddim10" / "run.json", {"data_split": {"demos": 10}})
    # and an explore stage trains the same DP on 50 demonstrations, read on those validation episodes: 35 of 50
    more = _study(tmp_path / "pick50", p, "hard", {"dp50@ddim10": dp(35)})
    write_json(more / "runs" / "dp50@ddim10" / "run.json", {"data_split": {"demos": 50}})
    write_json(out / "across.json", {"tasks": ["../drawer", "../peg", "../pick"], "more_demos": {p: "../pick50"}})
    md = Path(write_across_report(out)["markdown"]).read_text()
    line = next(x for x in md.splitlines() if x.startswith("- **metaworld/pick-place**: twice"))
    assert "twice the steps (training seed 0's check): +0.040 [" in line and "over 1 of 1 settings" in line
    assert ("demonstration count: Diffusion Policy DDIM10 (training seed 0) from 50 demonstrations 70% against 20% "
            "from 10 on the same 50 validation episodes: +0.500 [") in line
    assert line.endswith("(paired; one training seed each; pick50).")
    assert "metaworld/pick-place: twice the steps" in (out / "report" / "report.html").read_text()

    # a better policy with no check of its own: its line says so, then reads the task's other policies' checks
    write_json(pick / "runs" / "bct@default" / "eval-default.json", _eval("bct", "BCT", p, "hard", 20))  # 40%
    line = next(x for x in Path(write_across_report(out)["markdown"]).read_text().splitlines()
                if x.startswith("- **metaworld/pick-place**: twice"))
    assert line.startswith("- **metaworld/pick-place**: twice the steps: no twice-the-steps check yet; the other "
                           "policies' checks: Diffusion Policy +0.040 ["), line
    assert "] (inconclusive, training seed 0); demonstration count: Diffusion Policy DDIM10" in line
    shutil.rmtree(pick / "runs" / "bct@default")

    # a stage with nothing evaluated yet, and one whose run differs in more than its demonstrations, read nothing
    write_json(more / "runs" / "dp50@ddim10" / "run.json", {"data_split": {"demos": 50},
                                                            "overrides": {"pred_horizon": 16}})
    line = next(x for x in Path(write_across_report(out)["markdown"]).read_text().splitlines()
                if x.startswith("- **metaworld/pick-place**: twice"))
    assert line.endswith("demonstration count: pick50's 1 evaluation pairs with none of this study's check bases (the "
                         "same policy, setting and training seed, differing in its demonstration count alone): nothing "
                         "to read."), line
    (more / "runs" / "dp50@ddim10" / "eval-ddim10.json").unlink()
    md = Path(write_across_report(out)["markdown"]).read_text()
    assert "demonstration count: pick50 has no evaluation yet." in md
    # an evaluation of a setting the confirm run has no check file of (yet): not read as a mismatch
    write_json(more / "runs" / "dp50@ddim10" / "run.json", {"data_split": {"demos": 50}})
    write_json(more / "runs" / "dp50@ddpm10" / "eval-ddpm10.json", dp(35) | {"policy": {
        **dp(35)["policy"], "sampler": "ddpm"}})
    line = next(x for x in Path(write_across_report(out)["markdown"]).read_text().splitlines()
                if x.startswith("- **metaworld/pick-place**: twice"))
    assert line.endswith("demonstration count: pick50's 1 evaluation has no check base in this study (a check of the "
                         "same policy, setting and training seed): nothing to read."), line


def test_a_stage_in_larger_frames_pairs_with_the_check_base_where_the_frame_is_its_one_difference(tmp_path):
    out = _two_tasks(tmp_path)
    p = "metaworld/pick-place"

    def dp(successes: int, task: str = p) -> dict:
        return _eval("diffusion", "Diffusion Policy", task, "hard", successes, variant=("ddim", 10))

    pick = _study(tmp_path / "pick", p, "hard", {"dp@ddim10": dp(6)})
    write_json(pick / "runs" / "dp@ddim10" / "check-ddim10.json", dp(10))  # the check base: 20% of 50
    write_json(pick / "runs" / "dp@ddim10" / "run.json", {"data_split": {"demos": 10}})
    # the same DP on the same 10 demonstrations seen at 128 px (crop with it), on those validation episodes: 30 of 50
    big = _study(tmp_path / "pick128", f"{p}@128", "hard", {"dp128@ddim10": dp(30, f"{p}@128")})
    frame = {"data_split": {"demos": 10}, "overrides": {"image_size": 128, "crop": 112},
             "preset_values": {"image_size": 96, "crop": 84}}
    write_json(big / "runs" / "dp128@ddim10" / "run.json", frame)
    write_json(out / "across.json", {"tasks": ["../drawer", "../peg", "../pick"], "larger_frame": {p: "../pick128"}})
    md = Path(write_across_report(out)["markdown"]).read_text()
    line = next(x for x in md.splitlines() if x.startswith("- **metaworld/pick-place**: twice"))
    assert "demonstration count: no stage with more demonstrations yet; frame size: Diffusion Policy DDIM10 " in line
    assert ("(training seed 0) at 128 px 60% against 20% at 96 px on the same 50 validation episodes: +0.400 ["
            in line) and line.endswith("(paired; one training seed each; pick128).")
    assert "| pick128 |" in md  # its compute counts beside the confirm studies'
    # a stage that changed more than its frame (its demonstrations, another setting, its split) pairs with nothing
    for more in ({"data_split": {"demos": 50}}, {"overrides": {**frame["overrides"], "pred_horizon": 16}},
                 {"data_split": {"demos": 10, "split_seed": 1}}):
        write_json(big / "runs" / "dp128@ddim10" / "run.json", {**frame, **more})
        md = Path(write_across_report(out)["markdown"]).read_text()
        assert ("frame size: pick128's 1 evaluation pairs with none of this study's check bases (the same policy, "
                "setting and training seed, differing in its frame size alone): nothing to read.") in md, more


def test_the_compute_each_study_recorded_is_summed_with_its_machines(tmp_path):
    out = _two_tasks(tmp_path)  # drawer: 4 evaluations of 50 episodes; peg: 3
    zen3 = {"cpu_model": "AMD EPYC", "cpu_id": "AuthenticAMD family 25 model 1", "cpu_flags": ["avx2"]}
    zen5 = {"cpu_model": "AMD EPYC", "cpu_id": "AuthenticAMD family 26 model 2", "cpu_flags": ["avx512_bf16"]}
    runs = tmp_path / "drawer" / "runs"
    # a training in two sessions on two machines, and one on one: 1,800 s + 5,400 s of optimiser steps
    write_json(runs / "dp0@ddim10" / "train_summary.json", {"train_time_s": 1800.0, "hardware": zen3,
                                                            "segments": [zen5, zen3]})
    write_json(runs / "cnn@default" / "train_summary.json", {"train_time_s": 5400.0, "hardware": zen3})
    write_json(runs / "cnn@default" / "latency-default.json", {"type": "latency", "hardware": zen3, "modes": {}})
    # the study's index: the hours are its report's sums (training from the runs' records, evaluation its seconds)
    (tmp_path / "drawer" / "index.jsonl").write_text("".join(json.dumps(r) + "\n" for r in (
        {"stage": "train", "file": "runs/dp0@ddim10/train_summary.json", "seconds": 9999.0},
        {"stage": "train", "file": "runs/cnn@default/train_summary.json", "seconds": 9999.0},
        {"stage": "eval", "file": "runs/cnn@default/eval-default.json", "seconds": 720.0})))
    md = Path(write_across_report(out)["markdown"]).read_text()
    # every machine named once, sorted; _eval's records name "test cpu"
    both = ("AMD EPYC [AuthenticAMD family 25 model 1] (avx2); AMD EPYC [AuthenticAMD family 26 model 2] "
            "(avx512_bf16); test cpu")
    assert f"| drawer | 2 | 2.00 | 4 (200) | 0.20 | 1 | {both} |" in md
    assert "| peg | 0 | 0.00 | 3 (150) | 0.00 | 0 | test cpu |" in md
    assert f"| **total** | 2 | 2.00 | 7 (350) | 0.20 | 1 | {both} |" in md


def test_when_each_tasks_latencies_were_timed_is_said_sitting_by_sitting(tmp_path):
    """A latency compares with one of the same sitting: the note under the table says when each task's timings ran,
    split where no timing ran for 30 min (a stage's start is its end less its seconds)."""
    out = _two_tasks(tmp_path)
    md = Path(write_across_report(out)["markdown"]).read_text()
    assert "Timed (UTC" not in md  # nothing timed: nothing said

    def stage(end: str, seconds: float, kind: str = "latency", run: str = "") -> str:
        return json.dumps({"stage": kind, "file": f"runs/{run or end}/latency-default.json", "seconds": seconds,
                           "finished": end}) + "\n"

    (tmp_path / "drawer" / "index.jsonl").write_text(
        stage("2026-12-06T09:00:00+00:00", 60, run="a")  # timed again at 17:33: its file holds the later timing
        + stage("2026-12-06T17:33:00+00:00", 60, run="a") + stage("2026-12-06T17:36:00+00:00", 30)
        + stage("2026-12-06T18:10:00+00:00", 120, "eval")  # not a timing: no sitting of its own
        + stage("2026-12-07T00:04:00+00:00", 30) + stage("2026-12-07T00:40:00+00:00", 7 * 60))
    (tmp_path / "peg" / "index.jsonl").write_text(stage("2026-12-06T23:59:30+00:00", 60)
                                                  + stage("2026-12-07T01:01:00+01:00", 20))  # UTC 00:01
    md = Path(write_across_report(out)["markdown"]).read_text()
    # 00:04 and 00:40 are 29 min apart once the second's 7 min are counted: one sitting; a sitting over midnight
    assert ("Timed (UTC; a sitting ends where no timing ran for 30 min): metaworld/drawer-open 2 sittings, "
            "2026-12-06 17:32-17:36, 2026-12-07 00:03-00:40; metaworld/peg-insert-side 2026-12-06 23:58-"
            "2026-12-07 00:01. A latency compares with one of the same sitting") in md


def test_a_label_splits_at_its_top_level_commas_and_a_shared_part_is_listed_once():
    from bcbench.analysis.across_cells import _parts, common_parts

    assert _parts("ResNet-50 CNN, 10 demos, 1/8 width (0.48 M, random init)") == [
        "ResNet-50 CNN", "10 demos", "1/8 width (0.48 M, random init)"]
    assert _parts("a), b, c") == ["a)", "b", "c"]  # a stray ")" does not stop later commas splitting
    assert common_parts(["X, a, a", "Y, a"]) == ["a"]  # listed once
    assert common_parts(["X, a"]) == [] and common_parts(["X", "Y"]) == []  # one row; nothing but the names


def test_a_rows_control_rate_and_horizon_come_from_its_record_and_draw_its_budget_lines(tmp_path):
    """Figure 5's budget lines from real records: the task's control_hz and the run's action_horizon survive the
    merge over training seeds; Push-T's records from before tasks read 10 Hz; another task's record without its rate
    reads none (the analysis cannot know it), so it adds no line of another task's."""
    from bcbench.analysis.figures import budgets, row_budgets
    from bcbench.analysis.results import load_rows
    from bcbench.analysis.seeds import merge_training_seeds

    d = "metaworld/drawer-open"

    def dp(seed: int, rate: float | None) -> dict:
        ev = _eval("diffusion", "Diffusion Policy", d, "easy", 40 + seed, seed=seed, variant=("ddim", 10))
        ev["policy"]["config"]["action_horizon"] = 3
        if rate is None:
            del ev["task"]  # written before records held their task
        else:
            ev["task"]["control_hz"] = rate
        return ev

    _study(tmp_path / "new", d, "easy", {f"dp{s}@ddim10": dp(s, 80.0) for s in range(3)})
    rows = merge_training_seeds(load_rows(tmp_path / "new"))
    assert [(r.control_hz, r.action_horizon, r.seed_ids) for r in rows] == [(80.0, 3, [0, 1, 2])]
    assert row_budgets(rows) == budgets(80.0, [3]) and [ms for ms, _ in row_budgets(rows)] == [12.5, 37.5]
    _study(tmp_path / "old", d, "easy", {"dp0@ddim10": dp(0, None)})
    assert [r.control_hz for r in load_rows(tmp_path / "old")] == [None]
    assert row_budgets(load_rows(tmp_path / "old")) == ()
    pusht = _eval("cnn_mlp", "CNN-MLP", "pusht", None, 30)
    pusht["policy"]["config"]["action_horizon"] = 8
    del pusht["task"], pusht["eval_config"]  # a Push-T record from before tasks
    _study(tmp_path / "pusht", "pusht", None, {"cnn@default": pusht})
    assert row_budgets(load_rows(tmp_path / "pusht")) == ((100.0, "10 Hz, re-plan every step (100 ms)"),
                                                          (800.0, "10 Hz, re-plan every 8 steps (800 ms)"))


def test_a_task_studys_test_informed_decision_is_said_at_the_top_and_listed_under_provenance(tmp_path):
    out = _two_tasks(tmp_path)
    md = Path(write_across_report(out)["markdown"]).read_text()
    assert "informed by a test-seed result" not in md  # none recorded: no line
    spec = json.loads((tmp_path / "peg" / "spec.json").read_text())
    spec["test_informed"] = [{"decision": "a check of CNN-MLP added after its test score", "read": "runs/*/eval.json"}]
    write_json(tmp_path / "peg" / "spec.json", spec)
    paths = write_across_report(out)
    md, page = Path(paths["markdown"]).read_text(), Path(paths["html"]).read_text()
    head = md.split("## Success and latency per task")[0]
    assert "Against the protocol, 1 decision(s)" in head and "Against the protocol, 1 decision(s)" in page
    provenance = md.split("## Provenance")[1]
    assert ("- metaworld/peg-insert-side: Informed by a test-seed result, against the protocol (peg): a check of "
            "CNN-MLP added after its test score (read: runs/*/eval.json)") in provenance


def test_a_figure_with_nothing_to_draw_leaves_no_earlier_drawing_in_the_folder(tmp_path):
    out = _two_tasks(tmp_path)
    stale = out / "report" / "fig3_metaworld-drawer-open.png"  # drawer has one step count: no Figure 3 now
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"an earlier drawing")
    write_across_report(out)
    assert not stale.exists()
