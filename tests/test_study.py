"""Study specs, resumable studies (kill and rerun), the findings' verdicts, and the report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bcbench.analysis.report import write_report
from bcbench.errors import BCBenchError
from bcbench.study.spec import load_spec, parse_spec
from tests.tiny import TINY


def _spec_text(tmp_path) -> str:
    tiny = ", ".join(f'"{k}" = {json.dumps(v)}' for k, v in TINY["cnn_mlp"].items())
    dp = ", ".join(f'"{k}" = {json.dumps(v)}' for k, v in TINY["diffusion"].items())
    return f"""
[study]
name = "tiny"
episodes = 2
max_steps = 8
latency = true
latency_min_calls = 2
latency_min_seconds = 0.0
realtime = {{ delays = [1], execution = ["async"], measured = false, strategies = ["naive", "ensemble"] }}

[[run]]
policy = "random"
realtime = true

[[run]]
policy = "cnn_mlp"
set = {{ {tiny}, "optim.max_steps" = 2, "optim.batch_size" = 4 }}

[[run]]
policy = "diffusion"
set = {{ {dp}, "optim.max_steps" = 2, "optim.batch_size" = 4, "optim.warmup_steps" = 0 }}
eval = [{{ sampler = "ddpm", steps = [2] }}, {{ sampler = "ddim", steps = [2] }}]
"""


@pytest.mark.parametrize("text, message", [
    ("", "no runs"),
    ("[[run]]\npolicy = 'nope'", "unknown policy 'nope'"),
    ("[[run]]\npolicy = 'cnn_mlp'\nconfig = 'huge'", "unknown preset 'huge'"),
    ("[[run]]\npolicy = 'cnn_mlp'\neval = [{sampler='ddim', steps=[10]}]", "apply to generative policies only"),
    ("[[run]]\npolicy = 'diffusion'\neval = [{sampler='dpm', steps=[10]}]", "sampler must be ddpm or ddim"),
    ("[[run]]\npolicy = 'diffusion'\neval = [{sampler='ddim', steps=[0]}]", "steps must be whole numbers"),
    ("[[run]]\npolicy = 'cnn_mlp'\nmax_minutes = -1", "max_minutes must be a positive number"),
    ("[[run]]\npolicy = 'cnn_mlp'\nminutes = 5", "'minutes' is no longer a training budget"),
    ("[[run]]\npolicy = 'cnn_mlp'\nsteps = 0", "steps must be a whole number >= 1"),
    ("[[run]]\npolicy = 'diffusion'\neval = [{sampler='ddim', steps=[10], spacing='middle'}]", "spacing must be"),
    ("[study]\ndevice = 'tpu'\n[[run]]\npolicy = 'random'", "study.device"),
    ("[[run]]\npolicy = 'cnn_mlp'\nset = {'optim.nope' = 1}", "unknown config field"),
    ("[[run]]\npolicy = 'cnn_mlp'\ncolour = 'red'", "unknown key(s) colour"),
    ("[study]\nepisodes = 0\n[[run]]\npolicy = 'random'", "study.episodes"),
    ("[study]\nrealtime = {strategies = ['smooth']}\n[[run]]\npolicy = 'random'", "study.realtime.strategies"),
    ("[study]\nrealtime = {rtc_jacobian = 'no'}\n[[run]]\npolicy = 'random'", "study.realtime.rtc_jacobian"),
    # the seed protocol: an explore study (where choices are made) never reads the test seeds 100000-100099
    ("[study]\npurpose = 'explore'\nepisodes = 50\n[[run]]\npolicy = 'random'", "validation seeds"),
    ("[study]\npurpose = 'explore'\nseed_start = 99990\nepisodes = 50\n[[run]]\npolicy = 'random'",
     "validation seeds"),
    ("[study]\npurpose = 'explore'\nseed_start = 200000\nepisodes = 20\n[[run]]\npolicy = 'random'",
     "episodes >= 50"),
    ("[study]\npurpose = 'confirm'\nseed_start = 200000\n[[run]]\npolicy = 'random'", "test seeds from 100000"),
    ("[study]\npurpose = 'tune'\n[[run]]\npolicy = 'random'", "purpose must be explore or confirm"),
    ("[studdy]\n[[run]]\npolicy = 'random'", "unknown key(s) in the spec: studdy"),
])
def test_bad_specs_are_clear_errors(text, message, tmp_path):
    import tomllib

    with pytest.raises(BCBenchError, match=message.replace("(", r"\(").replace(")", r"\)")):
        parse_spec(tomllib.loads(text), "x.toml")


def test_bad_toml_and_missing_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[run]\npolicy=")
    with pytest.raises(BCBenchError, match="not valid TOML"):
        load_spec(bad)
    from bcbench.cli.main import main

    assert main(["study", str(tmp_path / "none.toml")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_shipped_specs_are_valid():
    for name in ("quick", "paper", "demo"):
        spec = load_spec(f"studies/{name}.toml")
        policies = {r.policy for r in spec.runs}
        assert {"cnn_mlp", "resnet50", "bet", "bct", "diffusion"} <= policies
        assert spec.episodes == (20 if name == "demo" else 40)


@pytest.mark.parametrize("path", sorted((Path(__file__).parents[1] / "studies").glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_spec_builds_its_configs(path):
    """Every committed spec parses and every run's config (preset plus `set` overrides) is valid."""
    spec = load_spec(path)
    keys = [r.key(spec.val_fraction) for r in spec.runs if r.learned]
    assert spec.runs and len(set(keys)) == len(keys)  # no two runs train the same thing


def test_config_hash_changes_with_the_config():
    import tomllib

    a = parse_spec(tomllib.loads("[[run]]\npolicy='cnn_mlp'"), "a").runs[0]
    b = parse_spec(tomllib.loads("[[run]]\npolicy='cnn_mlp'\nset={hidden=10}"), "b").runs[0]
    assert a.key(0.1) != b.key(0.1) and a.key(0.1) != a.key(0.2) and a.key(0.1) == a.key(0.1)


def test_a_runs_steps_are_its_budget_whatever_the_presets_epochs():
    """`steps` beyond what the preset's epochs hold still runs: the 32,000-step arm of cpu-explore-dpflow (a098acf)
    stopped at the cpu preset's 60 epochs, 20,520 steps. Epochs the spec gives itself stay."""
    import tomllib

    from bcbench.policies import make_config

    run = parse_spec(tomllib.loads("[[run]]\npolicy='diffusion'\npreset='cpu'\nsteps=32000"), "a").runs[0]
    cfg = make_config("diffusion", "cpu", run.overrides)
    assert cfg.optim.max_steps == 32000 and cfg.optim.epochs >= 32000  # >= 1 step per epoch: steps bind
    own = parse_spec(tomllib.loads("[[run]]\npolicy='diffusion'\npreset='cpu'\nsteps=500\nset={'optim.epochs'=3}"),
                     "b").runs[0]
    assert make_config("diffusion", "cpu", own.overrides).optim.epochs == 3


KILL_AFTER_3_STAGES = """
import os, signal, sys
from bcbench.study import StudyRunner
from bcbench.study.spec import load_spec
class Killed(StudyRunner):
    def after_stage(self):
        if self.executed == 3:
            os.kill(os.getpid(), signal.SIGKILL)
Killed(load_spec(sys.argv[1]), sys.argv[2], sys.argv[3], progress=False).run()
"""


def test_study_killed_then_rerun_resumes_without_redoing(synthetic_zarr, tmp_path, capsys):
    from bcbench.cli.main import main  # the reruns in-process (a subprocess each cost 10 s of start-up)

    spec = tmp_path / "tiny.toml"
    spec.write_text(_spec_text(tmp_path))
    out = tmp_path / "out"
    cmd = ["study", str(spec), "--out", str(out), "--data", str(synthetic_zarr), "--quiet"]
    proc = subprocess.run([sys.executable, "-c", KILL_AFTER_3_STAGES, str(spec), str(out), str(synthetic_zarr)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == -9, proc.stderr  # SIGKILL after 3 finished stages
    index = [json.loads(x) for x in (out / "index.jsonl").read_text().splitlines()]
    assert [i["stage"] for i in index] == ["eval", "train", "eval"]  # timing comes after every evaluation
    first_files = {i["file"]: (out / i["file"]).stat().st_mtime_ns for i in index}
    assert main(cmd) == 0
    assert "3 already done" in capsys.readouterr().out
    for f, mtime in first_files.items():
        assert (out / f).stat().st_mtime_ns == mtime  # finished stages were not redone
    index = [json.loads(x) for x in (out / "index.jsonl").read_text().splitlines()]
    # random: eval, latency, realtime naive and ensemble; cnn: train, eval, latency; dp: train, 2+2
    assert len(index) == 4 + 3 + 5
    assert not list(out.rglob(".realtime-*.partial.json"))  # a finished sweep leaves no partial file behind
    report = out / "report" / "report.md"
    assert report.exists() and (out / "report" / "report.html").exists()
    text = report.read_text()
    assert "The study's findings" in text and "DDPM2" in text
    assert "## Under real-time execution" in text and "async-d1" in text and (out / "report" / "realtime.png").exists()
    assert "## Execution strategies under latency" in text and "| random (quick) | ensemble |" in text
    learned = [json.loads(f.read_text()) for f in out.rglob("latency-*.json")]
    learned = [r for r in learned if "fast" in r["modes"]]
    fast = [r["modes"]["fast"] for r in learned]  # every mode's median against this machine's floor
    assert fast and all(m["x_floor"] > 0 and m["machine_limits"]["read_gb_per_s"] > 0 for m in fast)
    assert f"({learned[0]['modes']['fast']['x_floor']:.1f}x)" in text
    assert main([*cmd, "--no-report"]) == 0  # the report was checked above: 4-5 s of figures saved per rerun
    assert "0 stage(s) run" in capsys.readouterr().out
    # a new machine (no run folder) goes on from the committed export: every finished stage is skipped
    from bcbench.study.restore import restore

    assert main(["report", str(out), "--export", str(tmp_path / "export")]) == 0
    restored = tmp_path / "restored"
    assert restore(tmp_path / "export", restored) == json.loads((out / index[0]["file"]).read_text())["git_commit"]
    assert not (restored / "report").exists() and not list(restored.rglob("*.safetensors"))
    assert main([*cmd[:3], str(restored), *cmd[4:], "--no-report"]) == 0
    assert "0 stage(s) run" in capsys.readouterr().out


def _study_stages():
    import importlib.util

    path = Path(__file__).parents[1] / "scripts" / "study_stages.py"
    mod_spec = importlib.util.spec_from_file_location("study_stages", path)
    stages = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(stages)
    return stages


def test_study_stages_runs_timing_first_and_the_study_then_skips_it(synthetic_zarr, tmp_path, capsys):
    """scripts/study_stages.py: a study's timing and real-time stages now, recorded as the study records them (the
    study's later run skips them); stages whose training is not done here are refused before anything runs."""
    from bcbench.cli.main import main

    stages = _study_stages()
    text = _spec_text(tmp_path)
    spec = tmp_path / "tiny.toml"
    spec.write_text(text)
    out = tmp_path / "out"
    assert stages.main([str(spec), str(out), "latency"]) == 2  # cnn_mlp's and DP's trainings are not done here
    assert "need a training that is not done here" in capsys.readouterr().err and not (out / "index.jsonl").exists()
    assert stages.main([str(spec), str(out), "lateny"]) == 2  # a misspelt kind is an error, not a quiet no-op
    assert "lateny: not a stage kind" in capsys.readouterr().err
    assert stages.main(["--trained", str(spec), str(out), "latency"]) == 0  # only the random baseline's timing
    assert "3 stage(s) wait for a training" in capsys.readouterr().out  # cnn_mlp once, DP in its two settings
    assert [json.loads(x)["stage"] for x in (out / "index.jsonl").read_text().splitlines()] == ["latency"]
    spec.write_text(text[:text.index("[[run]]\npolicy = \"cnn_mlp\"")])  # the random baseline only
    assert stages.main([str(spec), str(out), "latency", "realtime"]) == 0
    index = [json.loads(x) for x in (out / "index.jsonl").read_text().splitlines()]
    assert [i["stage"] for i in index] == ["latency", "realtime", "realtime"]  # the timing above, then the sweeps
    assert all((out / i["file"]).is_file() for i in index)
    assert stages.main(["--again", str(spec), str(out), "latency", "realtime"]) == 2  # a timing only, not a sweep
    assert "runs latency stages only" in capsys.readouterr().err
    timed = json.loads((out / index[0]["file"]).read_text())
    assert stages.main(["--again", str(spec), str(out), "latency"]) == 0  # timed again, in this sitting
    again = [json.loads(x) for x in (out / "index.jsonl").read_text().splitlines()][len(index):]
    assert [(i["stage"], i["file"]) for i in again] == [("latency", index[0]["file"])]
    assert json.loads((out / index[0]["file"]).read_text()) != timed  # the file holds the new timing
    assert main(["study", str(spec), "--out", str(out), "--data", str(synthetic_zarr), "--quiet", "--no-report"]) == 0
    assert "1 stage(s) run, 3 already done" in capsys.readouterr().out  # only the evaluation was left


def test_study_stages_any_seed_times_seed_1_where_seed_0_is_not_trained(synthetic_zarr, tmp_path, capsys):
    """--any-seed: a label's latency stage (its lowest seed, 0) whose network is not here times the same label's seed
    1, trained here, into seed 1's folder as the study records a latency stage; the flag times latency only. A seed-0
    run restored from an export (its finished training's record, no checkpoint) is not trained here either."""
    from bcbench.study.runner import StudyRunner
    from bcbench.utils.io import read_json

    stages = _study_stages()
    tiny = ", ".join(f'"{k}" = {json.dumps(v)}' for k, v in TINY["cnn_mlp"].items())
    spec = tmp_path / "tiny.toml"
    spec.write_text(f"""
[study]
name = "tiny"
episodes = 2
max_steps = 8
latency_min_calls = 2
latency_min_seconds = 0.0

[[run]]
policy = "cnn_mlp"
seeds = [0, 1]
set = {{ {tiny}, "optim.max_steps" = 2, "optim.batch_size" = 4 }}
""")
    out = tmp_path / "out"
    runner = StudyRunner(load_spec(spec), out, str(synthetic_zarr), progress=False)
    s0, s1 = sorted(runner.spec.runs, key=lambda r: r.seed)
    runner.finish("train", s1, None, runner.compute("train", s1, None), 0.0)  # seed 1 trained here, seed 0 not
    assert stages.main(["--any-seed", str(spec), str(out), "latency", "eval"]) == 2  # a timing only
    err = capsys.readouterr().err
    assert "--any-seed" in err and "runs latency stages only" in err and len(err.strip().splitlines()) == 1
    assert stages.main([str(spec), str(out), "latency"]) == 2  # without the flag seed 0's timing waits for it
    assert "need a training that is not done here" in capsys.readouterr().err
    assert stages.main(["--any-seed", "--trained", str(spec), str(out), "latency"]) == 0
    printed = capsys.readouterr().out
    assert "s1 stands in for s0" in printed and "1 stage(s) run" in printed
    timed = runner.result_file("latency", s1, s1.variants[0])
    index = [json.loads(x) for x in (out / "index.jsonl").read_text().splitlines()]
    assert [(i["stage"], i["seed"], i["file"]) for i in index] == [
        ("train", 1, f"runs/{runner.run_dir(s1).name}/train_summary.json"),
        ("latency", 1, str(timed.relative_to(out)))]
    record = read_json(timed)  # which weights ran: seed 1's, by folder, seed and hash
    assert Path(record["policy"]["run_dir"]).name == runner.run_dir(s1).name and record["policy"]["weights_sha256"]
    assert record["policy"]["config"]["seed"] == 1 and record["study"]["label"] == s0.label
    assert list(out.rglob("latency-*.json")) == [timed] and not runner.run_dir(s0).exists()
    assert stages.main(["--any-seed", str(spec), str(out), "latency"]) == 0  # timed already: nothing to do
    assert "0 stage(s) run" in capsys.readouterr().out
    assert stages.main(["--any-seed", "--again", str(spec), str(out), "latency"]) == 0  # in this sitting again
    assert "1 stage(s) run" in capsys.readouterr().out and read_json(timed) != record
    # seed 0 restored from an export: its finished training's record, but no checkpoint (its weights stayed behind)
    runner.run_dir(s0).mkdir(parents=True)
    (runner.run_dir(s0) / "train_summary.json").write_text((runner.run_dir(s1) / "train_summary.json").read_text())
    assert runner.is_done("train", s0, None)
    assert stages.main(["--trained", str(spec), str(out), "latency"]) == 0  # waits: not "has no checkpoint yet"
    assert "1 stage(s) wait for a training" in capsys.readouterr().out


def test_restore_refuses_an_existing_folder_and_mixed_commits(tmp_path):
    from bcbench.study.restore import restore
    from bcbench.utils.io import write_json

    export = tmp_path / "export"
    write_json(export / "spec.json", {})
    (export / "index.jsonl").write_text("")
    write_json(export / "runs" / "a" / "eval-default.json", {"git_commit": "c1"})
    write_json(export / "runs" / "b" / "eval-default.json", {"git_commit": "c2"})
    with pytest.raises(BCBenchError, match="carry 2 commits"):
        restore(export, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    write_json(export / "runs" / "b" / "eval-default.json", {"git_commit": "c1"})
    (tmp_path / "taken").mkdir()
    with pytest.raises(BCBenchError, match="exists"):
        restore(export, tmp_path / "taken")
    with pytest.raises(BCBenchError, match="not an exported study"):
        restore(tmp_path / "taken", tmp_path / "out")
    assert restore(export, tmp_path / "out") == "c1" and (tmp_path / "out" / "runs" / "b").exists()


@pytest.mark.parametrize("last", ["a", "b"])
def test_restore_goes_on_at_the_newest_pin_of_a_study_that_says_why_it_mixes_commits(tmp_path, last):
    from bcbench.study.restore import restore
    from bcbench.utils.io import write_json

    export = tmp_path / "export"
    write_json(export / "spec.json", {})
    write_json(export / "runs" / "a" / "eval-default.json", {"git_commit": "c1"})
    write_json(export / "runs" / "b" / "eval-default.json", {"git_commit": "c2"})
    order = ["b", "a"] if last == "a" else ["a", "b"]  # index.jsonl lists stages in the order they finished
    (export / "index.jsonl").write_text("".join(json.dumps({"file": f"runs/{r}/eval-default.json"}) + "\n"
                                                for r in order))
    with pytest.raises(BCBenchError, match=r"no mixing-reason\.txt says why"):
        restore(export, tmp_path / "out")
    (export / "mixing-reason.txt").write_text("the pin moved when the spec gained resources; same code\n")
    assert restore(export, tmp_path / "out") == {"a": "c1", "b": "c2"}[last]
    assert (tmp_path / "out" / "mixing-reason.txt").exists()  # the account travels with the study


def test_report_from_fixture_files(tmp_path):
    """A hand-made results directory: the report reads files only and draws every figure."""
    from bcbench.utils.io import write_json

    def ev(policy, label, score, variant=None, schedule=None, params=1000):
        lo, hi = max(0, score - 0.1), min(1, score + 0.1)
        est = {"value": score, "ci95": [lo, hi]}
        pol = {"name": policy, "parameters": params, "config": {"beta_schedule": schedule} if schedule else {}}
        if variant:
            pol.update({"sampler": variant[0], "steps": variant[1]})
        episodes = [{"seed": 100_000 + i, "score": score + 0.1 * ((i % 3) - 1)} for i in range(40)]
        return {"type": "evaluation", "policy": pol, "study": {"label": label}, "episodes": episodes,
                "summary": {"n": 40, "mean_score": est, "share_above_0.5": est, "share_above_0.9": est,
                            "success_rate": est}, "hardware": {"cpu_model": "test cpu", "torch_threads": 2},
                "git_commit": "abc123"}

    def lat(ms):
        m = {"median_ms": ms, "p99_ms": ms * 1.2, "tail_ms": ms * 1.2, "tail_stat": "p99",
             "max_rate_every_step_hz": 1000 / ms}
        return {"type": "latency", "modes": {"reference": m, "fast": {**m, "median_ms": ms / 2}},
                "git_commit": "abc123"}

    runs = tmp_path / "runs"
    write_json(runs / "cnn" / "eval-default.json", ev("cnn_mlp", "CNN-MLP", 0.3))
    write_json(runs / "cnn" / "latency-default.json", lat(2.0))
    write_json(runs / "cnn" / "train_summary.json", {"epochs": 3.0, "train_time_s": 600, "samples_per_s": 150,
                                                     "stopped": "finished", "git_commit": "abc123"})
    from bcbench.utils.io import append_jsonl

    for step, score in ((100, 0.2), (200, 0.28), (300, 0.3), (400, 0.29)):  # a flat last quarter: converged
        point = {"value": score, "ci95": [score - 0.1, score + 0.1]}
        append_jsonl(runs / "cnn" / "metrics.jsonl", {"step": step, "samples": 64 * step, "val_loss": 0.1 / step,
                                                      "eval_score": point})
    write_json(runs / "bct" / "eval-default.json", ev("bct", "BCT", 0.3))
    write_json(runs / "bct" / "train_summary.json", {"epochs": 0.1, "train_time_s": 6, "stopped": "finished",
                                                     "git_commit": "abc123"})
    for sampler, schedule in (("ddpm", "squaredcos_cap_v2"), ("ddim", "squaredcos_cap_v2"), ("ddim", "linear")):
        d = runs / f"dp-{schedule}"
        for k in (10, 100):
            write_json(d / f"eval-{sampler}{k}.json", ev("diffusion", "DP", 0.5, (sampler, k), schedule, 91_123_778))
            write_json(d / f"latency-{sampler}{k}.json", lat(10.0 * k))
    paths = write_report(tmp_path)
    md = Path(paths["markdown"]).read_text()
    for fig in ("fig5_accuracy_vs_latency.png", "fig3_denoising_steps.png", "fig4_samplers.png"):
        assert (tmp_path / "report" / fig).stat().st_size > 1000 and fig in md
    assert "0.29 / 25.0% / 2.5% / 2.20" in md  # the study's CNN-MLP numbers beside ours
    assert "10 denoising steps score as well as 100**: *supported*" in md and "Rule: DDPM-10 minus DDPM-100" in md
    assert "Produced at commit: abc123." in md and "mix several commits" not in md
    assert "- CNN-MLP: converged: fitted rise over the last quarter -0.010 (2 points, last 0.290)" in md
    assert "- BCT: **not converged**: 0 rollout point(s)" in md
    assert "ResNet-50 > BCT > CNN-MLP in score**: *inconclusive*" in md  # no ResNet-50: not judged at all
    assert (tmp_path / "report" / "learning_curves.png").stat().st_size > 1000
    html = Path(paths["html"]).read_text()
    assert html.count("data:image/png;base64,") == 4  # self-contained


def test_export_copies_results_but_no_checkpoints(tmp_path):
    from bcbench.analysis.export import export_results
    from bcbench.utils.io import write_json

    src = tmp_path / "study"
    write_json(src / "runs" / "a" / "eval-default.json", {"x": 1})
    write_json(src / "runs" / "a" / "train_summary.json", {"x": 1})
    (src / "runs" / "a" / "checkpoints" / "step_1").mkdir(parents=True)
    (src / "runs" / "a" / "checkpoints" / "step_1" / "model.safetensors").write_bytes(b"w")
    assert export_results(src, tmp_path / "out") == (2, [])
    assert not (tmp_path / "out" / "runs" / "a" / "checkpoints").exists()


def test_export_leaves_out_a_run_still_training(tmp_path):
    """A run whose training has not ended cannot be carried on from an export (no checkpoints), and a restoring
    machine would append a new training's curve to its files: the export leaves it out."""
    from bcbench.analysis.export import export_results
    from bcbench.utils.io import write_json

    src = tmp_path / "study"
    write_json(src / "spec.json", {})
    (src / "index.jsonl").write_text("")
    for run, summary in (("done", {"stopped": "finished"}), ("timed", {"stopped": "stopped by time: schedule not "
                                                                      "finished"}),
                         ("interrupted", {"stopped": "interrupted"}), ("training", None)):
        write_json(src / "runs" / run / "run.json", {"git_commit": "c1"})
        write_json(src / "runs" / run / "eval-default.json", {"git_commit": "c1"})
        if summary:
            write_json(src / "runs" / run / "train_summary.json", summary)
    write_json(src / "runs" / "baseline" / "eval-default.json", {"git_commit": "c1"})  # nothing to train
    n, left_out = export_results(src, tmp_path / "out")
    assert n == 9 and [d.name for d in left_out] == ["interrupted", "training"]
    assert sorted(p.name for p in (tmp_path / "out" / "runs").iterdir()) == ["baseline", "done", "timed"]


def test_study_time_sums_the_recorded_work(tmp_path):
    """Optimiser time over every session of a resumed run, its curve rollouts, and each other stage's seconds."""
    from bcbench.analysis.report import time_lines
    from bcbench.analysis.results import study_time
    from bcbench.utils.io import append_jsonl, write_json

    run = tmp_path / "runs" / "dp"
    write_json(run / "train_summary.json", {"train_time_s": 5400.0, "train_time_s_this_session": 60.0})
    for wall in (30.0, 90.0):
        append_jsonl(run / "metrics.jsonl", {"step": 1, "eval_wall_s": wall})
    append_jsonl(run / "metrics.jsonl", {"step": 2, "train_loss": 0.1})
    stages = [("train", "runs/dp/train_summary.json", 61.0), ("eval", "runs/dp/eval-a.json", 600.0),
              ("eval", "runs/dp/eval-b.json", 300.0), ("latency", "runs/dp/latency-a.json", 120.0),
              ("realtime", "runs/dp/realtime-a.json", 3600.0)]
    for stage, file, seconds in stages:
        append_jsonl(tmp_path / "index.jsonl", {"stage": stage, "file": file, "seconds": seconds})
    assert study_time(tmp_path) == {"training": 5400.0, "curve rollouts": 120.0, "evaluation": 900.0,
                                    "timing": 120.0, "real-time sweep": 3600.0}
    text = "\n".join(time_lines(tmp_path))
    assert "training 90 min, curve rollouts 2 min, evaluation 15 min, timing 2 min, real-time sweep 60 min" in text
    assert "Training, evaluation and timing: 1.82 h; with the real-time sweep: 2.82 h" in text
    assert time_lines(tmp_path / "nothing") == []


def test_report_lists_what_a_run_changed_in_its_preset():
    """A study's `set` (batch, lr) is a recipe change the report must name; bookkeeping and budget are not. The
    preset's values come from the run's own file (run.json's preset_values, which new_run writes)."""
    from bcbench.analysis.report import preset_change_lines
    from bcbench.analysis.results import Row

    def row(label, variant, run="", **overrides):
        return Row(key=f"{label}{run}:{variant}", label=label, policy="diffusion", preset="cpu", variant=variant,
                   sampler="ddpm", steps=100, spacing="trailing", beta_schedule=None, params=1, summary={},
                   overrides=overrides, preset_values={"optim.batch_size": 256, "optim.lr": 1e-3})

    rows = [row("DP as preset", "ddpm100", **{"optim.checkpoint_every": 7, "optim.max_steps": 99, "seed": 0}),
            row("DP batch 64", "ddpm100", **{"optim.batch_size": 64, "optim.lr": 5e-4}),
            row("DP batch 64", "ddim10", **{"optim.batch_size": 64, "optim.lr": 5e-4}),
            row("DP batch 64", "ddim10", run=" s1", **{"optim.batch_size": 64, "optim.lr": 5e-4})]  # another seed
    assert preset_change_lines(rows) == [
        "- DP batch 64 changes its cpu preset: optim.batch_size 64 (preset 256), optim.lr 0.0005 (preset 0.001)"]


def test_runner_refuses_test_seeds_in_an_explore_study(tmp_path):
    """A spec built in code (not parsed) is checked again where the study starts: nothing runs, nothing is written."""
    from bcbench.study import run_study

    spec = parse_spec({"study": {"purpose": "explore", "seed_start": 200000, "episodes": 50},
                       "run": [{"policy": "random"}]})
    spec.seed_start = 100000
    with pytest.raises(BCBenchError, match="validation seeds"):
        run_study(spec, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_provenance_reads_every_file_kind_and_states_the_reason(tmp_path):
    """A study completed later (a sweep, a re-timing) shows every commit with what it produced, and its reason."""
    from bcbench.analysis.provenance import provenance_notes
    from bcbench.analysis.results import file_commits

    run = tmp_path / "runs" / "r"
    run.mkdir(parents=True)
    (run / "eval-default.json").write_text(json.dumps({"git_commit": "aaa"}))
    (run / "train_summary.json").write_text(json.dumps({"git_commit": "aaa"}))
    (run / "realtime-default.json").write_text(json.dumps({"git_commit": "bbb"}))
    (tmp_path / "latency-paired.json").write_text(json.dumps({"git_commit": "ccc"}))
    (tmp_path / "latency-paired-fast.json").write_text(json.dumps({"git_commit": "ccc"}))  # not "timing" as well
    commits = file_commits(tmp_path)
    assert commits == {"aaa": ["evaluations", "training"], "bbb": ["real-time sweeps"], "ccc": ["interleaved latency"]}
    notes = provenance_notes([], commits, "sweeps added later")
    assert "aaa (evaluations, training), bbb (real-time sweeps), ccc (interleaved latency)" in notes[0]
    assert "mix several commits" in notes[1] and notes[1].endswith("Why: sweeps added later")
    assert provenance_notes([], {"aaa": ["evaluations"]}) == ["Produced at commit: aaa."]  # one commit: no warning


def test_provenance_says_whether_an_interleaved_timing_ran_on_a_quiet_machine():
    from bcbench.analysis.provenance import paired_conditions

    quiet = {"file": "latency-paired.json", "contention": {"other_cpus": 0.02, "steal_cpus": 0.0, "seconds": 180.0}}
    busy = {"file": "latency-paired-fast.json", "contention": {"other_cpus": 1.06, "steal_cpus": 0.1, "seconds": 9.0}}
    lines = paired_conditions({"reference": quiet, "fast": busy, "old": {"file": "latency-paired-old.json"}})
    assert lines == ["The interleaved timing latency-paired.json ran on a quiet machine (0.02 CPUs other, 0.00 stolen, "
                     "over 180 s).",
                     "Warning: the interleaved timing latency-paired-fast.json ran beside other work (1.06 CPUs other, "
                     "0.10 stolen, over 9 s): its times are not quiet-machine times."]


def test_provenance_names_the_timings_taken_beside_other_work():
    """A timing records what else used the CPUs; the report warns about the rows timed on a busy machine, and says so
    when every recorded timing was quiet (older files, which recorded nothing, are neither)."""
    from bcbench.analysis.provenance import timing_conditions
    from bcbench.analysis.results import Row

    def row(label: str, **modes: dict) -> Row:
        return Row(key=label, label=label, policy="diffusion", preset="cpu", variant="ddim10", sampler="ddim",
                   steps=10, spacing=None, beta_schedule=None, params=1, summary={}, latency=modes)

    quiet = {"median_ms": 5.0, "cpu_contention": {"other_cpus": 0.01, "steal_cpus": 0.0, "seconds": 2.0}}
    busy = {"median_ms": 9.0, "cpu_contention": {"other_cpus": 0.97, "steal_cpus": 0.0, "seconds": 2.0}}
    assert timing_conditions([row("a", fast=quiet)]) == (
        "Every one of the 1 timings that recorded it ran on a quiet machine (other processes and the hypervisor's "
        "steal under 0.1 CPUs each).")
    note = timing_conditions([row("a", fast=quiet), row("DP", reference=busy, fast={"median_ms": 4.0})])
    assert note.startswith("Warning: 1 of 2 timings") and "DP ddim10 reference (0.97 CPUs other" in note
    assert timing_conditions([row("old", fast={"median_ms": 4.0})]) == ""


def test_twice_the_steps_decides_convergence():
    """The 2x check: paired over shared episodes, two-sided; strict studies need it, older ones keep the curve rule."""
    import dataclasses

    import numpy as np

    from bcbench.analysis.convergence import apply_checks, doubling_checks
    from bcbench.analysis.results import Row

    base_scores = np.random.default_rng(0).uniform(0.2, 0.8, 60)

    def row(label, scores, doubles=None):
        return Row(key=f"{label}:ddim10", label=label, policy="diffusion", preset="cpu", variant="ddim10",
                   sampler="ddim", steps=10, spacing="trailing", beta_schedule=None, params=1,
                   summary={"mean_score": {"value": float(np.mean(scores)), "ci95": [0, 1]}},
                   scores={200_000 + i: float(s) for i, s in enumerate(scores)}, converged=True, run_label=label,
                   doubles=doubles)

    same = [row("DP", base_scores), row("DP 2x", base_scores + 0.01, doubles="DP")]
    better = [row("DP", base_scores), row("DP 2x", base_scores + 0.2, doubles="DP")]
    (c,) = doubling_checks(same, 0.05)
    assert c.verdict == "converged" and c.n == 60 and c.run == "DP"
    assert doubling_checks(better, 0.05)[0].verdict == "not converged"
    apply_checks(better, doubling_checks(better, 0.05), strict=True, margin=0.05)
    assert better[0].converged is False and "twice the steps" in better[0].convergence
    assert "+0.200 [+0.200, +0.200] over 1 of 1 settings, not converged" in better[0].convergence
    # settings in sampler order, steps as numbers; each row gives both runs' means and the paired difference
    many = [row("DP", base_scores), row("DP 2x", base_scores + 0.2, doubles="DP")]
    for steps in (100, 2, 5):
        many += [dataclasses.replace(r, variant=f"ddim{steps}", steps=steps) for r in many[:2]]
    checks = doubling_checks(many, 0.05)
    assert [c.variant for c in checks] == ["ddim2", "ddim5", "ddim10", "ddim100"]
    assert f"| {np.mean(base_scores):.3f} | {np.mean(base_scores) + 0.2:.3f} | +0.200" in checks[0].table_row()
    apply_checks(many, checks, strict=True, margin=0.05)
    assert "over 4 of 4 settings, not converged; setting by setting 4 not converged" in many[0].convergence
    lone = [row("BCT", base_scores)]
    apply_checks(lone, [], strict=False, margin=0.05)
    assert lone[0].converged is True  # an older study: the curve rule stands (the report says what it is worth)
    apply_checks(lone, [], strict=True, margin=0.05)
    assert lone[0].converged is False and "no twice-the-steps check" in lone[0].convergence
    # the report tells a run awaiting its check from one that failed it
    from bcbench.analysis.report import convergence_lines

    assert convergence_lines(lone)[0].startswith("- BCT: **not shown converged**: no twice-the-steps check yet")
    assert convergence_lines(better[:1])[0].startswith("- DP: **not converged**: twice the steps")


def test_a_run_is_judged_on_its_settings_pooled():
    """The 2x verdict per run: settings whose own intervals straddle the margin but whose per-episode differences
    average out pass together; a setting both runs fail is left out of the pool; one setting clearly above the
    margin fails the run whatever the pool says."""
    import dataclasses

    import numpy as np

    from bcbench.analysis.convergence import CONVERGED, INCONCLUSIVE, NOT_CONVERGED, apply_checks, doubling_checks
    from bcbench.analysis.results import Row

    rng = np.random.default_rng(1)
    n = 100
    base = rng.uniform(0.5, 1.0, n)

    def row(label, variant, scores, doubles=None):
        return Row(key=f"{label}:{variant}", label=label, policy="flow", preset="cpu", variant=variant,
                   sampler="euler", steps=int(variant.removeprefix("euler")), spacing=None, beta_schedule=None,
                   params=1, summary={"mean_score": {"value": float(np.mean(scores)), "ci95": [0, 1]}},
                   scores={200_000 + i: float(x) for i, x in enumerate(scores)}, converged=True, run_label=label,
                   doubles=doubles)

    def study(shifts, noise=0.3, broken=()):
        rows = []
        for k, shift in enumerate(shifts):
            v = f"euler{k + 1}"
            run = np.full(n, 0.05) if v in broken else base
            twice = np.full(n, 0.05) if v in broken else base + shift + rng.normal(0, noise, n)  # independent noise
            rows += [row("flow", v, run), row("flow 2x", v, twice, doubles="flow")]
        return rows

    # eight settings, no true gain: each setting's own interval is about +/-0.06, so some are inconclusive and
    # requiring every setting to pass would not show the run converged ...
    rows = study([0.0] * 8)
    checks = doubling_checks(rows, 0.05)
    assert any(c.verdict == INCONCLUSIVE for c in checks)
    verdicts = apply_checks(rows, checks, strict=True, margin=0.05)
    v = verdicts["flow", None]  # ... the average over them is about +/-0.02 wide and passes
    assert v.verdict == CONVERGED and v.hi < 0.05 and (v.hi - v.lo) < 0.5 * min(c.hi - c.lo for c in checks)
    assert rows[0].converged is True and "over 8 of 8 settings, converged" in rows[0].convergence
    # a setting both runs fail (DP with one step) is not averaged in: its zero difference would dilute the pool
    rows = study([0.1] * 3, noise=0.1, broken=("euler1",))
    v = apply_checks(rows, doubling_checks(rows, 0.05), strict=True, margin=0.05)["flow", None]
    assert v.pooled == ["euler2", "euler3"] and v.est > 0.085 and v.verdict == NOT_CONVERGED  # diluted: 0.067
    # one setting gaining clearly fails the run though the pool's interval lies below the margin
    rows = study([0.0] * 7 + [0.3], noise=0.05)
    checks = doubling_checks(rows, 0.05)
    v = apply_checks(rows, checks, strict=True, margin=0.05)["flow", None]
    assert v.hi < 0.05 and checks[-1].verdict == NOT_CONVERGED and v.verdict == NOT_CONVERGED
    assert rows[0].converged is False
    # where neither is decided the run is inconclusive, and not shown converged
    rows = study([0.05] * 2)
    v = apply_checks(rows, doubling_checks(rows, 0.05), strict=True, margin=0.05)["flow", None]
    assert v.verdict == INCONCLUSIVE and rows[0].converged is False
    from bcbench.analysis.report import convergence_lines  # and the report says so, not "not converged"

    assert convergence_lines(rows[:1])[0].startswith("- flow: **not shown converged**: twice the steps")
    # two checked training seeds are pooled apart; a seed without its own check takes both verdicts
    same, gain = study([0.0] * 4), study([0.2] * 4, noise=0.05)
    rows = [dataclasses.replace(r, train_seed=0) for r in same] + [dataclasses.replace(r, train_seed=1) for r in gain]
    unchecked = dataclasses.replace(rows[0], train_seed=2)
    verdicts = apply_checks([*rows, unchecked], doubling_checks(rows, 0.05), strict=True, margin=0.05)
    assert verdicts["flow", 0].verdict == CONVERGED and verdicts["flow", 1].verdict == NOT_CONVERGED
    assert rows[0].converged is True and rows[len(same)].converged is False and unchecked.converged is False


@pytest.mark.parametrize("doubled, message", [
    ('{ policy = "cnn_mlp", label = "2x", steps = 30, doubles = "base" }', "twice the optim.max_steps"),
    ('{ policy = "cnn_mlp", label = "2x", steps = 40, doubles = "nope" }', "not a run of the same policy"),
    ('{ policy = "cnn_mlp", label = "2x", doubles = "base" }', "must both state steps"),
])
def test_a_doubling_run_is_checked(doubled, message):
    import tomllib

    text = f'run = [{{ policy = "cnn_mlp", label = "base", steps = 20 }}, {doubled}]'
    with pytest.raises(BCBenchError, match=message):
        parse_spec(tomllib.loads(text))
    ok = parse_spec(tomllib.loads('run = [{ policy = "cnn_mlp", label = "base", steps = 20 }, '
                                  '{ policy = "cnn_mlp", label = "2x", steps = 40, doubles = "base" }]'))
    assert ok.runs[1].doubles == "base"


def test_the_recipe_a_report_states_is_each_runs_own_config_not_a_recorded_text():
    """A run's recorded deviation text went stale once (it named batch 256 and lr 1e-3 for a run trained at 64 and
    5e-4), so the report no longer reads it: the network comes from bcbench.reference, the recipe from each run's
    config."""
    from bcbench.analysis.report import deviation_lines
    from bcbench.analysis.results import Row, recipe_text

    optim = {"optimizer": "adamw", "lr": 5e-4, "batch_size": 64, "epochs": 20400, "max_steps": 20400,
             "schedule": "cosine", "warmup_steps": 100, "precision": "fp32", "ema": True}
    assert recipe_text(optim) == "adamw lr 0.0005, batch 64, 20,400 steps, cosine, 100 warm-up steps, fp32, EMA"
    row = Row(key="r:ddim10", label="DP", policy="diffusion", preset="cpu", variant="ddim10", sampler="ddim",
              steps=10, spacing=None, beta_schedule=None, params=1, summary={},
              recipe=recipe_text(optim))
    line = deviation_lines([row])[2]
    assert "stale" not in line and line.endswith("trained as run: " + recipe_text(optim)) and "U-Net" in line


def test_a_resumed_runs_training_cell_states_its_overall_rate_beside_its_last_sessions():
    """train_summary's samples/s is its last session's; beside the run's total minutes it read as a contradiction
    (DP seed 0: 112 min at '389 samples/s' for 1.3 M samples), so a resumed run also states samples / minutes."""
    from bcbench.analysis.report import _train_cell
    from bcbench.analysis.results import Row

    def cell(**train):
        return _train_cell(Row(key="r", label="DP", policy="diffusion", preset="cpu", variant="ddim10",
                               sampler="ddim", steps=10, spacing=None, beta_schedule=None, params=1, summary={},
                               train={"epochs": 1.0, "stopped": "finished", **train}))

    resumed = cell(samples=600_000, train_time_s=3000.0, samples_per_s=400.0)
    assert "50.0 min, 200 samples/s overall (400 in its last session)" in resumed
    one_session = cell(samples=600_000, train_time_s=1500.0, samples_per_s=400.0)
    assert "25.0 min, 400 samples/s;" in one_session + ";" and "overall" not in one_session
    # a session recorded before cpu_id existed is the same CPU as one with it (model, flags, precision): named once
    xeon = {"cpu_model": "Xeon", "cpu_flags": ["avx2"], "precision": "fp32"}
    segs = [xeon, {**xeon, "cpu_id": "family 6 model 207"}, {**xeon, "cpu_model": "EPYC"}]
    assert cell(samples=1, train_time_s=1.0, segments=segs).endswith(
        "trained on EPYC (avx2), fp32 and Xeon [family 6 model 207] (avx2), fp32")


def test_a_restored_run_gets_its_published_weights_back_and_nothing_else_does(tmp_path, capsys):
    """A new machine's restored study finds seed 0's inference weights in models/ (same run.json, sha256 checked),
    so its timing and real-time stages can run; other studies' models, runs with checkpoints and tampered weights
    are left alone or refused."""
    import hashlib

    import torch
    from safetensors.torch import save_file

    from bcbench.study.restore import attach_published, main
    from bcbench.utils.io import write_json

    run = {"policy": "diffusion", "config": {"seed": 0}, "git_commit": "c1"}
    models = tmp_path / "models"
    ckpt = models / "dp" / "checkpoints" / "step_0000010"
    ckpt.mkdir(parents=True)
    save_file({"w": torch.ones(3)}, str(ckpt / "ema.safetensors"))
    write_json(models / "dp" / "checkpoints" / "latest.json", {"step": 10, "dir": "step_0000010"})
    write_json(models / "dp" / "run.json", run)
    sha = hashlib.sha256((ckpt / "ema.safetensors").read_bytes()).hexdigest()
    meta = {"weights": "ema", "source": {"run": "dp-s0", "checkpoint": "step_0000010", "git_commit": "c1"},
            "file": {"path": "checkpoints/step_0000010/ema.safetensors", "sha256": sha}}
    write_json(models / "dp" / "model.json", meta)
    out = tmp_path / "study"
    write_json(out / "runs" / "dp-s0" / "run.json", run)
    write_json(out / "runs" / "other-s0" / "run.json", {**run, "git_commit": "c2"})
    assert attach_published(out, models) == ["dp-s0: step_0000010 (ema weights) from " + str(models / "dp")]
    assert (out / "runs" / "dp-s0" / "checkpoints" / "step_0000010" / "ema.safetensors").read_bytes() == \
        (ckpt / "ema.safetensors").read_bytes()
    assert not (out / "runs" / "other-s0" / "checkpoints").exists()
    assert attach_published(out, models) == []  # idempotent: the run now has checkpoints
    main(["--attach", str(out), str(models)])  # the command line says nothing on stdout (it carries the commit)
    assert capsys.readouterr().out == ""
    for bad in ([], [str(out)], ["--attach", str(out), str(models), "extra"], ["--attach"]):
        with pytest.raises(SystemExit) as exit_:
            main(bad)
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and err.count("\n") == 1 and "error:" in err, bad
    # the same run name at another commit is another study's run: left alone
    other = tmp_path / "other"
    write_json(other / "runs" / "dp-s0" / "run.json", {**run, "git_commit": "c2"})
    assert attach_published(other, models) == []
    # a run.json that differs at the same commit, or weights that do not match their sha256: refused, nothing copied
    bad = tmp_path / "bad"
    write_json(bad / "runs" / "dp-s0" / "run.json", {**run, "config": {"seed": 1}})
    with pytest.raises(BCBenchError, match=r"run\.json differs"):
        attach_published(bad, models)
    save_file({"w": torch.zeros(3)}, str(ckpt / "ema.safetensors"))
    write_json(bad / "runs" / "dp-s0" / "run.json", run)
    with pytest.raises(BCBenchError, match="sha256"):
        attach_published(bad, models)
    assert not (bad / "runs" / "dp-s0" / "checkpoints").exists()


def test_a_restored_run_that_cannot_go_on_is_dropped_and_its_first_models_files_leave_the_export(tmp_path):
    """Trained on another machine, weights neither kept nor published, evaluations still to run: the run cannot go
    on, and a model retrained on another CPU must not have its scores mixed with the first one's. Restore drops it
    (folder and index lines; the study trains it again), and the next export removes the first model's files."""
    from bcbench.analysis.export import export_results
    from bcbench.study.restore import drop_unrunnable, main
    from bcbench.study.runner import StudyRunner
    from bcbench.utils.io import read_jsonl, write_json

    spec_file = tmp_path / "s.toml"
    spec_file.write_text("[study]\nlatency = false\n[[run]]\npolicy = 'diffusion'\nconfig = 'quick'\n"
                         "seeds = [0, 1, 2]\neval = [{ sampler = 'ddim', steps = [1, 2] }]\n")
    out = tmp_path / "study"
    runner = StudyRunner(load_spec(spec_file), out, progress=False)
    runs = [runner.run_dir(r) for r in runner.spec.runs]
    index = []
    for i, d in enumerate(runs):  # s0 and s1 evaluated at ddim1 only; s2 at both
        write_json(d / "run.json", {"git_commit": "c1"})
        write_json(d / "train_summary.json", {"stopped": "finished", "git_commit": "c1"})
        for v in ("ddim1", "ddim2") if i == 2 else ("ddim1",):
            write_json(d / f"eval-{v}.json", {"git_commit": "c1"})
            index.append(json.dumps({"stage": "eval", "run": d.name, "file": f"runs/{d.name}/eval-{v}.json"}))
    (runs[1] / "checkpoints").mkdir()  # s1 was trained here: it goes on
    (out / "index.jsonl").write_text("\n".join(index) + "\n")
    write_json(out / "spec.json", {})
    dest = tmp_path / "export"
    export_results(out, dest)  # what the last session committed: s0's first model included
    assert (dest / "runs" / runs[0].name / "eval-ddim1.json").exists()

    lines = drop_unrunnable(spec_file, out)
    assert len(lines) == 1 and lines[0].startswith(f"{runs[0].name}: trained on another machine with 1 stage(s)")
    assert not runs[0].exists() and runs[1].exists() and runs[2].exists()  # s2 is complete: nothing to run
    assert [json.loads(x)["run"] for x in (out / "index.jsonl").read_text().splitlines()] == \
        [runs[1].name, runs[2].name, runs[2].name]
    assert [r["run"] for r in read_jsonl(out / "dropped-runs.jsonl")] == [runs[0].name]
    main(["--attach", str(out), str(tmp_path / "no-models"), "--spec", str(spec_file)])  # idempotent
    assert [r["run"] for r in read_jsonl(out / "dropped-runs.jsonl")] == [runs[0].name]
    export_results(out, dest)  # the first model's files leave the committed export with it
    assert not (dest / "runs" / runs[0].name).exists() and (dest / "runs" / runs[2].name / "eval-ddim2.json").exists()
    assert (dest / "dropped-runs.jsonl").exists()


def test_a_study_without_its_tasks_demonstrations_stops_in_one_line_before_any_stage(tmp_path, monkeypatch):
    """A new machine's cache has no generated MetaWorld demonstrations: a study with a training to run says so once,
    before anything runs (the random baseline first in the spec, which needs none, does not run either)."""
    from bcbench.errors import DatasetError
    from bcbench.study import run_study

    monkeypatch.setenv("BCBENCH_HOME", str(tmp_path / "home"))
    spec = parse_spec({"study": {"task": "metaworld/pick-place", "episodes": 2},
                       "run": [{"policy": "random"}, {"policy": "cnn_mlp", "steps": 2}]})
    with pytest.raises(DatasetError, match=r"no MetaWorld demonstrations for metaworld/pick-place at .*bcbench data "
                                           r"generate --task metaworld/pick-place"):
        run_study(spec, tmp_path / "out", progress=False)
    assert not (tmp_path / "out" / "index.jsonl").exists()
