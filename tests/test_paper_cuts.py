"""What a newcomer hit on a fresh clone (issue 77), each fixed where it is behaviour: a published model evaluated in
the setting it is published with, named on the console; `latency --checkpoint`; one option name for the inference
mode on every command; no safe-delay verdict from a handful of episodes; no run folder left by a failed start."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bcbench.cli.main import main
from bcbench.modes import mode_name

MODELS = Path(__file__).resolve().parents[1] / "models"


def test_eval_of_a_published_model_runs_its_recorded_sampler_and_says_so(tmp_path, capsys):
    """models/diffusion-cpu's run defaults to DDPM-100; its published score is DDIM-10, which eval now runs."""
    assert main(["eval", "--checkpoint", str(MODELS / "diffusion-cpu"), "--episodes", "1", "--max-steps", "3",
                 "--out", str(tmp_path / "e"), "--quiet"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "sampler ddim, 10 steps (trailing spacing), mode fast" in first
    policy = json.loads((tmp_path / "e" / "eval.json").read_text())["policy"]
    assert (policy["sampler"], policy["steps"]) == ("ddim", 10)
    assert main(["eval", "--checkpoint", str(MODELS / "diffusion-cpu"), "--steps", "2", "--episodes", "1",
                 "--max-steps", "2", "--out", str(tmp_path / "f"), "--quiet"]) == 0
    assert ", 2 steps" in capsys.readouterr().out  # given options win (the run's own sampler fills the rest)


def test_latency_times_a_published_checkpoint_and_takes_evals_backend_name(tmp_path, capsys):
    out = tmp_path / "lat"
    assert main(["latency", "--checkpoint", str(MODELS / "bct-cpu"), "--backend", "torch", "--mode", "fast",
                 "--quick", "--out", str(out)]) == 0
    rows = json.loads((out / "latency.json").read_text())["rows"]
    assert [r["mode"] for r in rows] == ["fast", "fast"]  # torch = fast; --mode is the old name of --backend
    assert all(r["policy"] == "bct" and r["checkpoint"] == str(MODELS / "bct-cpu") and r["median_ms"] > 0
               for r in rows)


def test_a_mode_name_is_a_backend_too():
    assert mode_name("openvino-bf16") == "openvino-bf16" and mode_name("fast") == "fast"
    assert mode_name("openvino", "bf16") == "openvino-bf16"  # the old spelling still works
    with pytest.raises(Exception, match="names a mode already"):
        mode_name("openvino-fp32", "int8")


def test_realtime_gives_no_safe_delay_verdict_from_too_few_episodes(tmp_path, capsys):
    assert main(["realtime", "--policy", "scripted", "--delays", "1", "--execution", "async", "--episodes", "2",
                 "--max-steps", "10", "--out", str(tmp_path / "r"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "too few episodes to decide (2)" in out
    assert "Largest safe delay: " not in out and "highest safe control rate" not in out.replace(
        "Largest safe delay and highest safe control rate: too few", "")


def test_the_report_caps_the_control_rate_at_the_simulators_step_rate():
    from bcbench.analysis.realtime import rate_text

    assert rate_text(5599.4, "async, up to d = 1") == ("10 Hz (Push-T's step rate; calls alone allow 5599 Hz; "
                                                       "async, up to d = 1)")
    assert rate_text(7.5) == "7.5 Hz"


@pytest.mark.parametrize("bad", ["missing", "empty"])
def test_train_with_bad_data_leaves_no_run_folder(bad, tmp_path, capsys):
    data = tmp_path / "pusht.zarr"
    if bad == "empty":
        data.mkdir()  # exists, but holds no replay buffer: fails when training loads it
    run = tmp_path / "run"
    assert main(["train", "--policy", "bct", "--data", str(data), "--out", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "error" in err[0]
    assert not run.exists()
