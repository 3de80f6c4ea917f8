"""A MetaWorld task end to end at smoke size, through the command line as a user runs it: generate demonstrations,
train every learned policy a few steps, evaluate, time, sweep delays and run a study with --task. Skipped where
MetaWorld is not installed (make install installs it)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("metaworld", reason="MetaWorld is not installed (pip install 'bcbench[metaworld]')")

from bcbench.cli.main import main
from bcbench.policies import learned_policies
from tests.tiny import TINY

TASK = "metaworld/drawer-open"


def _sets(name: str) -> list[str]:
    tiny = {**TINY[name], "optim.max_steps": 2, "optim.epochs": 1, "optim.batch_size": 4,
            "optim.checkpoint_every": 2, "optim.warmup_steps": 0}
    return [a for k, v in tiny.items() for a in ("--set", f"{k}={json.dumps(v)}")]


@pytest.fixture(scope="module")
def demos(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("mw") / "demos.zarr"
    assert main(["data", "generate", "--task", TASK, "--episodes", "2", "--out", str(out), "--workers", "1",
                 "--quiet"]) == 0
    return out


@pytest.fixture(scope="module")
def dp_run(demos: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = tmp_path_factory.mktemp("mw") / "dp"
    assert main(["train", "--task", TASK, "--data", str(demos), "--policy", "diffusion", *_sets("diffusion"),
                 "--out", str(run), "--quiet"]) == 0
    return run


@pytest.mark.parametrize("name", learned_policies())
def test_every_learned_policy_trains_and_is_scored_on_a_metaworld_task(name, demos, tmp_path, capsys):
    run = tmp_path / name
    assert main(["train", "--task", TASK, "--data", str(demos), "--policy", name, *_sets(name), "--out", str(run),
                 "--quiet"]) == 0
    assert json.loads((run / "run.json").read_text())["task"] == TASK
    assert main(["eval", "--checkpoint", str(run), "--episodes", "1", "--max-steps", "6", "--workers", "1",
                 "--quiet", "--out", str(tmp_path / "eval")]) == 0
    rec = json.loads((tmp_path / "eval" / "eval.json").read_text())
    assert rec["eval_config"]["task"] == TASK and rec["policy"]["task"] == TASK
    assert rec["episodes"][0]["length"] == 6 and 0.0 <= rec["episodes"][0]["max_coverage"] <= 1.0


def test_eval_latency_and_realtime_on_a_metaworld_run(dp_run, demos, tmp_path, capsys, monkeypatch):
    import bcbench.analysis.figures as figures

    drawn = []  # the latency chart's budget lines: MetaWorld's 80 Hz step and chunk, not Push-T's 100 / 800 ms
    bars = figures.latency_bars
    monkeypatch.setattr(figures, "latency_bars", lambda *a: drawn.append(a[3]) or bars(*a))
    assert main(["eval", "--checkpoint", str(dp_run), "--episodes", "2", "--max-steps", "10", "--workers", "1",
                 "--quiet", "--out", str(tmp_path / "e")]) == 0
    assert main(["eval", "--checkpoint", str(dp_run), "--task", "pusht", "--episodes", "1"]) == 2
    assert "trained on metaworld/drawer-open, not pusht" in capsys.readouterr().err
    assert main(["data", "info", "--task", "metaworld/door-open", "--data", str(demos)]) == 2  # another task's store
    assert "holds demonstrations of metaworld/drawer-open, not metaworld/door-open" in capsys.readouterr().err
    assert main(["latency", "--checkpoint", str(dp_run), "--task", "pusht", "--quick", "--out", str(tmp_path)]) == 2
    assert main(["latency", "--checkpoint", str(dp_run), "--backend", "fast", "--quick", "--out",
                 str(tmp_path / "lat")]) == 0
    lat = json.loads((tmp_path / "lat" / "latency.json").read_text())
    assert lat["task"] == TASK and lat["rate_hz"] == 80.0 and lat["rows"][0]["calls"] >= 5
    k = lat["rows"][0]["action_horizon"]
    assert [ms for ms, _ in drawn[0]] == [12.5, 12.5 * k] and k > 1 and "80 Hz" in drawn[0][1][1]
    assert main(["realtime", "--checkpoint", str(dp_run), "--delays", "0", "2", "--execution", "async",
                 "--episodes", "2", "--max-steps", "10", "--quiet", "--out", str(tmp_path / "rt")]) == 0
    d2 = json.loads((tmp_path / "rt" / "realtime-async-d2.json").read_text())
    # a delay of 2 steps is 2 of MetaWorld's 12.5 ms steps, and every call saw d = 2
    assert d2["eval_config"]["latency_ms"] == pytest.approx(25.0) and set(d2["summary"]["delay_steps"]) == {"2"}


def test_a_study_runs_on_a_metaworld_task(demos, tmp_path):
    dp = ", ".join(f'"{k}" = {json.dumps(v)}' for k, v in TINY["diffusion"].items())
    spec = tmp_path / "mw.toml"
    spec.write_text(f"""
[study]
name = "mw-smoke"
episodes = 2
max_steps = 6
latency = true
latency_min_calls = 2
latency_min_seconds = 0.0

[[run]]
policy = "random"

[[run]]
policy = "diffusion"
set = {{ {dp}, "optim.max_steps" = 2, "optim.batch_size" = 4, "optim.warmup_steps" = 0 }}
eval = [{{ sampler = "ddim", steps = [2] }}]
""")
    out = tmp_path / "study"
    assert main(["study", str(spec), "--task", TASK, "--data", str(demos), "--out", str(out), "--quiet"]) == 0
    runs = [r for r in (out / "runs").iterdir() if (r / "run.json").exists()]
    assert len(runs) == 1 and json.loads((runs[0] / "run.json").read_text())["task"] == TASK
    chance = json.loads(next((out / "runs").glob("random-*/eval-default.json")).read_text())
    assert chance["eval_config"]["task"] == TASK and chance["policy"]["task"] == TASK  # random acts on this task
    evals = list(out.rglob("eval*.json"))
    assert evals and all(json.loads(f.read_text())["eval_config"]["task"] == TASK for f in evals)
    report = (out / "report" / "report.md").read_text()
    assert f"mw-smoke on {TASK}" in report and "the study's A100 numbers are Push-T's" in report
    row = next(line for line in report.splitlines() if line.startswith("| diffusion (quick)") and " M | " in line)
    assert row.rstrip(" |").endswith("-")  # no published Push-T number beside a MetaWorld row


def test_a_policy_trains_and_is_scored_on_larger_frames(tmp_path, capsys):
    """metaworld/NAME@128 end to end: its own demonstrations at 128 px, DP's encoder on them, scored in 128 px
    episodes. The network's image_size is part of its config (and run key), so it is set, not inferred: a config
    left at 96 is refused in one line that says what to set."""
    task, data, run = "metaworld/drawer-open@128", tmp_path / "big.zarr", tmp_path / "dp"
    assert main(["data", "generate", "--task", task, "--episodes", "2", "--out", str(data), "--workers", "1",
                 "--quiet"]) == 0
    train = ["train", "--task", task, "--data", str(data), "--policy", "diffusion", *_sets("diffusion"), "--quiet"]
    assert main([*train, "--out", str(tmp_path / "refused")]) == 2
    assert "image_size is 96, task metaworld/drawer-open@128's frames 128: --set image_size=128" in \
        capsys.readouterr().err
    assert main([*train, "--set", "image_size=128", "--out", str(run)]) == 0
    assert json.loads((run / "run.json").read_text())["task"] == task
    assert main(["eval", "--checkpoint", str(run), "--episodes", "1", "--max-steps", "4", "--workers", "1",
                 "--quiet", "--out", str(tmp_path / "eval")]) == 0
    rec = json.loads((tmp_path / "eval" / "eval.json").read_text())
    assert rec["task"]["name"] == task and rec["task"]["image_size"] == 128 and rec["episodes"][0]["length"] == 4
