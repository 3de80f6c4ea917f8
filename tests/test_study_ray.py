"""Studies on Ray: the same result files as the in-process runner; resume across the two; clear errors."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from bcbench.errors import BCBenchError
from bcbench.study import run_study
from bcbench.study.spec import load_spec, parse_spec
from tests.tiny import TINY

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance (2 CPUs) for the module: the studies below join it and leave it running."""
    from bcbench.study.on_ray import NODE_RESOURCE, NODE_UNITS

    ray.init(num_cpus=2, resources={NODE_RESOURCE: NODE_UNITS}, include_dashboard=False, log_to_driver=False,
             logging_level="WARNING")
    yield
    ray.shutdown()


def _spec(tmp_path):
    tiny = ", ".join(f'"{k}" = {json.dumps(v)}' for k, v in TINY["cnn_mlp"].items())
    path = tmp_path / "tiny.toml"
    path.write_text(f"""
[study]
name = "tiny"
episodes = 2
max_steps = 8
threads = 1
latency_min_calls = 2
latency_min_seconds = 0.0
resources = {{ train = {{ cpus = 1 }}, eval = {{ cpus = 1 }} }}

[[run]]
policy = "scripted"

[[run]]
policy = "cnn_mlp"
set = {{ {tiny}, "optim.max_steps" = 3, "optim.batch_size" = 4 }}
""")
    return path


def _files(out):
    return sorted(str(p.relative_to(out)) for p in (out / "runs").rglob("*.json*") if "checkpoints" not in p.parts)


def _episodes(out, rel):
    return [(e["seed"], e["score"]) for e in json.loads((out / rel).read_text())["episodes"]]


def test_ray_study_writes_what_the_in_process_runner_writes(synthetic_zarr, tmp_path, local_ray):
    spec = load_spec(_spec(tmp_path))
    local = run_study(spec, tmp_path / "local", str(synthetic_zarr), progress=False)
    ray = run_study(spec, tmp_path / "ray", str(synthetic_zarr), progress=False, ray="local", ray_cpus=2)
    assert local["executed"] == ray["executed"] == 5  # scripted: eval, latency; cnn_mlp: train, eval, latency
    assert _files(tmp_path / "local") == _files(tmp_path / "ray")
    for rel in _files(tmp_path / "local"):
        if "/eval-" in rel:  # the same episodes, the same scores (timing fields aside)
            assert _episodes(tmp_path / "local", rel) == _episodes(tmp_path / "ray", rel)
    losses = [[json.loads(x).get("loss") for x in (d / "runs").glob("cnn_mlp-*/metrics.jsonl").__next__()
               .read_text().splitlines()] for d in (tmp_path / "local", tmp_path / "ray")]
    assert losses[0] == losses[1]  # the same training, step for step
    index = [json.loads(x) for x in (tmp_path / "ray" / "index.jsonl").read_text().splitlines()]
    timing = [i for i in index if i["stage"] == "latency"]
    assert len(timing) == 2 and all(i["node"] for i in timing)
    assert json.loads((tmp_path / "ray" / timing[0]["file"]).read_text())["node"]
    launch = [json.loads((tmp_path / d / "launch.json").read_text()) for d in ("local", "ray")]
    assert launch == [{"ray": False}, {"ray": True, "ray_cpus": 2}]  # the local instance's 2 CPUs (fixture)
    from pathlib import Path

    from bcbench.analysis.report import write_report

    report = Path(write_report(tmp_path / "ray")["markdown"]).read_text()
    assert "Timed on " in report  # the report says which machine timed what


KILL_AFTER_2_STAGES = """
import os, signal, sys
from bcbench.study import StudyRunner
from bcbench.study.spec import load_spec
class Killed(StudyRunner):
    def after_stage(self):
        if self.executed == 2:
            os.kill(os.getpid(), signal.SIGKILL)
Killed(load_spec(sys.argv[1]), sys.argv[2], sys.argv[3], progress=False).run()
"""


def test_killed_in_process_study_resumes_on_ray_without_redoing(synthetic_zarr, tmp_path, local_ray):
    spec, out = _spec(tmp_path), tmp_path / "out"
    proc = subprocess.run([sys.executable, "-c", KILL_AFTER_2_STAGES, str(spec), str(out), str(synthetic_zarr)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == -9, proc.stderr
    done = {i["file"]: (out / i["file"]).stat().st_mtime_ns
            for i in map(json.loads, (out / "index.jsonl").read_text().splitlines())}
    assert len(done) == 2
    summary = run_study(load_spec(spec), out, str(synthetic_zarr), progress=False, ray="local")
    assert summary["executed"] == 3 and summary["skipped"] == 2
    for f, mtime in done.items():
        assert (out / f).stat().st_mtime_ns == mtime  # nothing finished was redone
    index = [json.loads(x) for x in (out / "index.jsonl").read_text().splitlines()]
    assert len(index) == len({i["file"] for i in index}) == 5  # every stage once


def test_cli_flag_and_resource_specs_are_checked():
    from bcbench.cli.parser import build_parser

    assert build_parser().parse_args(["study", "s.toml", "--ray"]).ray == "local"
    assert build_parser().parse_args(["study", "s.toml", "--ray", "auto"]).ray == "auto"
    with pytest.raises(BCBenchError, match=r"study.resources must be a table"):
        parse_spec({"study": {"resources": {"training": {"cpus": 1}}}, "run": [{"policy": "random"}]})
    with pytest.raises(BCBenchError, match=r"study.resources.eval must be"):
        parse_spec({"study": {"resources": {"eval": {"cpus": 0}}}, "run": [{"policy": "random"}]})


def test_a_stage_given_n_cpus_runs_n_threads_and_a_check_reads_evals_resources():
    """Two 1-CPU trainings side by side can train more samples/s than one 2-thread training on 2 cores, so a
    stage runs as many torch threads as the CPUs its kind asks for (spec threads otherwise); a confirm study's
    check stage asks what an evaluation asks."""
    from bcbench.study.on_ray import _options, stage_cpus

    spec = parse_spec({"study": {"threads": 2, "resources": {"train": {"cpus": 1}, "eval": {"cpus": 1}}},
                       "run": [{"policy": "random"}]})
    assert [stage_cpus(spec, s) for s in ("train", "eval", "check", "latency")] == [1, 1, 1, 2]
    assert _options(spec, "check")["num_cpus"] == 1 and _options(spec, "latency")["resources"] == {
        "bcbench_node": 1000}


def test_a_ray_training_task_runs_the_threads_of_its_cpus(synthetic_zarr, tmp_path, local_ray):
    spec = load_spec(_spec(tmp_path))
    spec.threads = 2  # the spec's own; the training stage asks for 1 CPU
    run_study(spec, tmp_path / "ray", str(synthetic_zarr), progress=False, ray="local", ray_cpus=2)
    seg = json.loads(next((tmp_path / "ray" / "runs").glob("cnn_mlp-*/segments.jsonl")).read_text().splitlines()[0])
    assert seg["threads"] == 1


def test_the_driver_hands_ray_what_fits_evaluations_of_trained_runs_first_and_timing_last():
    """Ray starts queued tasks roughly in submission order, so the driver queues them itself: a finished training's
    evaluations must not wait behind every training submitted before them, nothing is queued beyond the free
    CPUs, and timing stages wait until nothing else is left."""
    from bcbench.study.on_ray import pick

    spec = parse_spec({"study": {"threads": 2, "resources": {"train": {"cpus": 1}, "eval": {"cpus": 1}}},
                       "run": [{"policy": "random", "seeds": [0, 1, 2]}]})
    a, b, c = spec.runs
    trains = [("train", r, None) for r in (a, b, c)]
    evals = [("eval", a, None), ("check", a, None), ("eval", a, "x")]
    timing = [("latency", a, None), ("realtime", a, None)]
    assert pick(spec, trains + evals + timing, 0, 2, True) == evals[:2]  # not the trainings listed before them
    assert pick(spec, trains + evals + timing, 1, 2, True) == evals[:1]  # one CPU free: one stage
    assert pick(spec, trains, 0, 2, True) == trains[:2]  # the study's order within a rank
    assert pick(spec, trains + timing, 2, 2, True) == []  # nothing free: nothing queued
    assert pick(spec, timing, 0, 2, True) == []  # a non-timing stage is left (running or waiting)
    assert pick(spec, timing, 0, 2, False) == timing  # the last stretch: Ray's node resource serialises them
    wide = parse_spec({"study": {"threads": 4}, "run": [{"policy": "random"}]})
    only = [("train", wide.runs[0], None)]
    assert pick(wide, only, 0, 2, True) == only  # wider than the cluster: it goes alone, not never
    assert pick(wide, only, 1, 2, True) == []
