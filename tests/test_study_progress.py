"""`bcbench study --status`: stages done, each training's step and rate, and the time left, from files only."""

from __future__ import annotations

import json

import pytest

from bcbench.study import progress
from bcbench.study.runner import StudyRunner
from bcbench.study.spec import parse_spec
from bcbench.utils.io import write_json
from tests.tiny import TINY


def _runner(tmp_path, resources=True):
    tiny = {**TINY["cnn_mlp"], "optim.batch_size": 4, "optim.max_steps": 1000}
    study = {"name": "st", "episodes": 2, "latency": False}
    if resources:
        study["resources"] = {"train": {"cpus": 1}, "eval": {"cpus": 1}}
    spec = parse_spec({"study": study, "run": [{"policy": "cnn_mlp", "seeds": [0, 1, 2], "set": tiny}]})
    out = tmp_path / "study"
    write_json(out / "spec.json", {"name": "st"})
    return StudyRunner(spec, out, progress=False)


def _training(runner, seed, steps, rate=40.0, done=False):
    """A run folder as the trainer leaves it: run.json, metrics every 100 steps at `rate` samples/s."""
    run = next(r for r in runner.spec.runs if r.seed == seed)
    d = runner.run_dir(run)
    write_json(d / "run.json", {"config": run.config_dict()})
    lines = [{"step": s, "epoch": s / 50, "samples": 4 * s, "train_time_s": 4 * s / rate}
             for s in range(100, steps + 1, 100)]
    lines.insert(2, {"step": 300, "eval_score": {"value": 0.5}})  # a learning-curve line: no samples, skipped
    (d / "metrics.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    if done:
        write_json(d / "train_summary.json", {"stopped": "finished"})


@pytest.mark.parametrize("cpus, left_s", [(2, 100.0), (1, 150.0)])
def test_status_reads_steps_rates_and_estimates_the_time_left(tmp_path, monkeypatch, cpus, left_s):
    monkeypatch.setattr(progress.os, "cpu_count", lambda: cpus)
    runner = _runner(tmp_path)
    _training(runner, 0, 500)  # 500 of 1,000 steps at 40 samples/s: 2,000 samples, 50 s left
    _training(runner, 2, 1000, rate=80.0, done=True)
    s = progress.status(runner)
    assert (s["done"]["train"], s["total"]["train"]) == (1, 3)
    (going,), (waiting,) = s["going"], s["waiting"]
    assert (going.run.seed, going.step, going.max_steps, going.batch) == (0, 500, 1000, 4)
    assert going.rate == pytest.approx(40.0) and going.seconds_left == pytest.approx(50.0)
    # seed 1 has not started: the rate of the run of its policy and batch still training (not the finished one's)
    assert waiting.run.seed == 1 and waiting.rate == pytest.approx(40.0)
    assert waiting.seconds_left == pytest.approx(100.0)
    # two lanes: 50 s and 100 s side by side; one lane: one after the other
    assert s["lanes"] == cpus and s["train_seconds_left"] == pytest.approx(left_s)
    text = progress.format_status(runner)
    assert "500 / 1,000 steps, 40 samples/s lately" in text
    assert ("2 side by side" if cpus == 2 else "one at a time") in text


@pytest.mark.parametrize("launch, lanes", [({"ray": False, "ray_cpus": 2}, 1), ({"ray": True, "ray_cpus": 4}, 4),
                                           ({"ray": True, "ray_cpus": 1}, 1)])
def test_the_time_left_follows_how_the_study_was_started(tmp_path, monkeypatch, launch, lanes):
    """A spec with `resources` started without Ray (BCBENCH_RAY=0) trains one run at a time: the estimate adds
    the trainings up instead of counting them side by side; under Ray its own CPU count sets the lanes."""
    monkeypatch.setattr(progress.os, "cpu_count", lambda: 2)
    runner = _runner(tmp_path)
    write_json(runner.out / progress.LAUNCH_FILE, launch)
    _training(runner, 0, 500)  # 50 s left; seeds 1 and 2 waiting, 100 s each at the same rate
    s = progress.status(runner)
    assert s["lanes"] == lanes
    assert s["train_seconds_left"] == pytest.approx({1: 250.0, 4: 100.0}[lanes])


def test_run_study_records_how_it_was_started(tmp_path, monkeypatch):
    from bcbench.study import run_study

    monkeypatch.setattr(StudyRunner, "run", lambda self: {"stages": 0})
    runner = _runner(tmp_path)
    run_study(runner.spec, runner.out, progress=False)
    assert json.loads((runner.out / progress.LAUNCH_FILE).read_text())["ray"] is False


def test_without_resources_trainings_run_one_at_a_time_and_unknown_rates_are_said(tmp_path):
    runner = _runner(tmp_path, resources=False)
    s = progress.status(runner)
    assert s["lanes"] == 1 and s["train_seconds_left"] is None and s["unknown"] == 3
    assert "training left" not in progress.format_status(runner)
    _training(runner, 0, 200)
    assert progress.status(runner)["train_seconds_left"] == pytest.approx((800 + 1000 + 1000) * 4 / 40.0)


def test_status_of_a_folder_that_is_no_study_is_one_line(tmp_path, capsys):
    from bcbench.cli.main import main

    spec = tmp_path / "s.toml"
    spec.write_text('[study]\nname = "s"\n\n[[run]]\npolicy = "scripted"\n')
    assert main(["study", str(spec), "--out", str(tmp_path / "nothing"), "--status"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no study folder" in err[0]
