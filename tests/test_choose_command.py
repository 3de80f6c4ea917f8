"""`bcbench choose`: which published model for a control loop on this machine. The reading and the rule (files
only, fast), the live parts on tiny counts (2 episodes, a few timed calls), bad input, and the page in Chromium."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bcbench.analysis.choose import choice, delay_steps, rank, strategy_at, with_evidence
from bcbench.analysis.published import Sweep, published_models, reproduction, sweep_records, sweeps_of
from bcbench.cli.main import main
from bcbench.errors import BCBenchError

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
SEEDS = range(100000, 100100)


def _setting(scores: dict[int, float]) -> dict:
    mean = sum(scores.values()) / len(scores)
    return {"summary": {"n": len(scores), "mean_score": {"value": mean, "ci95": [mean - 0.05, mean + 0.05]}},
            "episodes": [{"seed": s, "score": v} for s, v in scores.items()]}


def _sweep(strategy: str, d: int, scores: dict[int, float], horizon: int | None = None, name: str = "x") -> Sweep:
    return Sweep(Path(f"results/{name}-{strategy}/realtime-sweep.json"), strategy, horizon,
                 {"realtime-sync": _setting({s: 0.8 for s in SEEDS}), f"realtime-async-d{d}": _setting(scores)})


def test_delay_is_counted_from_the_tail_at_the_users_rate():
    assert delay_steps(1.3, 10) == 1  # a call takes at least one step
    assert delay_steps(100.0, 10) == 1 and delay_steps(100.1, 10) == 2
    assert delay_steps(45.0, 50) == 3  # 0.045 s x 50 Hz = 2.25 -> 3


def test_naive_is_kept_unless_a_strategy_beats_it_on_the_same_seeds():
    naive = _sweep("naive", 4, {s: 0.6 + 0.01 * (s % 3) for s in SEEDS})
    level = _sweep("ensemble", 4, {s: 0.6 + 0.01 * ((s + 1) % 3) for s in SEEDS})  # the same on average
    better = _sweep("rtc", 4, {s: 0.7 + 0.01 * (s % 3) for s in SEEDS}, horizon=8)
    assert strategy_at([naive, level], 4)["strategy"] == "naive"
    pick = strategy_at([naive, level, better], 4)
    assert pick["strategy"] == "rtc" and pick["horizon_text"] == "s = 8" and pick["versus_naive"][1] > 0
    assert strategy_at([naive], 2) is None  # nothing swept at d = 2


def _row(label: str, d: int, rt: float | None, sync: float = 0.8, live_only: bool = False) -> dict:
    row = {"label": label, "setting": "default", "d": d, "policy": "bct",
           "fastest": {"mode": "fast", "median_ms": 5.0, "tail_ms": 6.0, "tail_stat": "p99"}}
    if live_only:
        return {**row, "live_only": True}
    row["committed"] = {"value": sync, "ci95": [sync - 0.05, sync + 0.05]}
    if rt is not None:
        s = _sweep("naive", d, {k: rt + 0.01 * (k % 2) for k in SEEDS})
        row["realtime"] = strategy_at([s], d)
    return row


def test_the_highest_committed_score_at_its_own_delay_wins_and_live_scores_do_not_rank():
    rows = [_row("slow", 2, 0.70), _row("fast", 1, 0.75), _row("mine", 1, None, live_only=True),
            _row("unswept", 1, None, sync=0.99)]
    ranked, basis = rank(rows)
    assert basis == "realtime" and [r["label"] for r in ranked] == ["fast", "slow"]
    pick = choice(rows, 10.0, "Test CPU")
    assert pick["chosen"] == "fast" and pick["runner_up"] == "slow"
    assert pick["line"].startswith("At 10 Hz on Test CPU: use fast (default, fast): score 0.755")
    assert "median 5.0 ms, p99 6.0 ms" in pick["line"] and "leads it by +0.050" in pick["line"]
    # a runner-up the paired interval cannot tell from the choice is not said to be behind it
    tie = choice([_row("p", 1, 0.70), _row("q", 1, 0.70)], 10.0, "X")["line"]
    assert "not told apart from the choice" in tie and "leads it" not in tie
    # nothing swept at these delays: ranked on the committed sync score, and the line says so
    assert choice([_row("a", 3, None, 0.6), _row("b", 3, None, 0.7)], 10.0, "X")["chosen"] == "b"
    assert "no committed sweep" in choice([_row("a", 3, None, 0.6)], 10.0, "X")["line"]


def test_reproduction_says_exactly_within_or_by_how_much():
    assert reproduction({1: 0.5, 2: 1.0}, {1: 0.5, 2: 1.0, 3: 0.2})["verdict"] == "exactly"
    assert reproduction({1: 0.5000003}, {1: 0.5})["verdict"] == "within"
    rep = reproduction({1: 0.4, 2: 1.0}, {1: 0.5, 2: 1.0})
    assert rep["verdict"] == "differs" and rep["largest_difference"] == pytest.approx(0.1)


def test_the_committed_sweeps_of_a_published_model_are_found_its_own_study_first():
    models = {m.name: m for m in published_models(MODELS)}
    records = sweep_records(ROOT / "results")
    dp = sweeps_of(models["diffusion-cpu"], records)
    assert dp and "cpu-confirm-dpflow-long/runs/diffusion-cpu-s0-21c61ecc" in str(dp[0].path)
    assert {s.strategy for s in dp} >= {"naive", "rtc", "ensemble"}
    assert all(s.settings["realtime-sync"]["eval_config"]["seed_start"] == 100000 for s in dp)
    bct = sweeps_of(models["bct-cpu"], records)
    assert bct and all("bct" in str(s.path) for s in bct)
    row = with_evidence({"label": "bct-cpu", "setting": "cpu", "policy": "bct",
                         "fastest": {"mode": "fast", "median_ms": 2.0, "tail_ms": 3.0, "tail_stat": "p99"}},
                        models["bct-cpu"], records, ROOT, 10.0)
    naive = next(s for s in bct if s.strategy == "naive" and s.horizon is None)
    assert row["d"] == 1 and row["realtime"]["strategy"] == "naive" and row["realtime"]["file"] == str(naive.path)
    assert row["realtime"]["score"] == naive.settings["realtime-async-d1"]["summary"]["mean_score"]


def test_a_missing_or_empty_models_folder_is_one_error(tmp_path):
    with pytest.raises(BCBenchError, match="no models folder"):
        published_models(tmp_path / "nope")
    with pytest.raises(BCBenchError, match="holds no published models"):
        published_models(tmp_path)


@pytest.mark.parametrize("argv, message", [
    (["choose", "--rate", "0"], "expected a number > 0"),
    (["choose", "--models", "{tmp}/empty"], "holds no published models"),
    (["choose", "--models", "{tmp}/missing"], "no models folder"),
    (["choose", "--policy", "nosuch"], "unknown policy 'nosuch'"),
], ids=["rate-0", "empty-models", "missing-models", "unknown-policy"])
def test_bad_input_is_one_line_and_exit_2(argv, message, tmp_path, capsys, monkeypatch):
    (tmp_path / "empty").mkdir()
    monkeypatch.chdir(ROOT)  # models/ and results/ as on a clone
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv] + ["--out", str(tmp_path / "out")]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors (OneLineParser)
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("name", ["bct-cpu", "flow-cpu"], ids=["deterministic", "stochastic"])
def test_published_models_reproduce_their_committed_episodes(name):
    """BCT (deterministic) and flow (noise from each episode's own stream) re-scored on 2 test episodes in their
    committed setting match the committed per-episode scores: exactly on the CPU that made them, within floating
    point (1e-3, test_publish's rule) on another one or at another batch size."""
    from bcbench.analysis.published import committed_eval
    from bcbench.cli.policies import eval_namespace, load_eval_policy
    from bcbench.evaluation.choose import rescore

    model = {m.name: m for m in published_models(MODELS)}[name]
    policy, _ = load_eval_policy(eval_namespace(checkpoint=str(model.folder)))
    live = rescore(policy, 2, progress=False)
    rep = reproduction(dict(zip(live["seeds"], live["scores"], strict=True)), committed_eval(model, ROOT)[0])
    assert rep["seeds"] == [100000, 100001] and rep["verdict"] in ("exactly", "within"), rep


def test_choose_end_to_end_with_a_users_plugin(knn_site, synthetic_zarr, tmp_path):
    """One small published model and the knn plug-in: the table and the page name the answer, the plug-in is
    scored live and labelled so (not ranked), and every file is written."""
    models = tmp_path / "models"
    models.mkdir()
    (models / "bct-cpu").symlink_to(MODELS / "bct-cpu")
    env = {**os.environ, "PYTHONPATH": f"{knn_site}{os.pathsep}{ROOT / 'src'}"}
    out = tmp_path / "page"
    proc = subprocess.run([sys.executable, "-m", "bcbench.cli", "choose", "--models", str(models), "--results",
                           str(ROOT / "results"), "--policy", "knn", "--policy-arg", f"data={synthetic_zarr}",
                           "--episodes", "2", "--calls", "3", "--out", str(out), "--quiet"],
                          capture_output=True, text=True, env=env, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    first = proc.stdout.splitlines()[0]  # a miniature's setting says its size
    assert proc.stdout.startswith("At 10 Hz on ") and ": use bct-cpu (cpu; 1/4 width (1.12 M), " in first
    knn = next(line for line in proc.stdout.splitlines() if line.startswith("knn "))
    assert "scored live, 2 episodes (wide interval)" in knn
    record = json.loads((out / "choose.json").read_text())
    assert record["choice"]["chosen"] == "bct-cpu" and record["choice"]["basis"] == "realtime"
    bct = next(r for r in record["rows"] if r["label"] == "bct-cpu")
    assert bct["reproduction"]["verdict"] in ("exactly", "within") and bct["fastest"]["calls"] >= 3
    assert set(bct["modes"]) <= {"fast", "openvino-fp32", "onnxruntime-fp32"} and "fast" in bct["modes"]
    page = (out / "choose.md").read_text()
    assert page.splitlines()[2].startswith("**At 10 Hz on ") and "scored live, 2 episodes" in page
    assert (out / "choose.html").exists() and (out / "fig5_this_machine.png").exists()
    assert record["video"] and Path(record["video"]).exists()


_spec = importlib.util.spec_from_file_location("check_report", ROOT / "scripts" / "check_report.py")
check = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(check)


@pytest.mark.skipif(check.chromium() is None, reason="no Chromium on this machine")
def test_the_page_reads_in_one_screen(tmp_path):
    """The page of a full set of published models: the answer and the table inside a laptop's first screen, no
    sideways scrolling, the figure decoded (scripts/check_report.py, as the report is checked)."""
    from bcbench.analysis.choose_page import write_page

    rows = [_row(f"{p}-cpu-long", 1, 0.5 + 0.03 * i) for i, p in enumerate(
        ["diffusion", "diffusion-linear", "flow", "bct", "bet", "bet", "resnet50", "resnet50", "cnn_mlp"])]
    rows.append({**_row("knn", 1, None, live_only=True), "rescored": "scored live, 5 episodes (wide interval): "
                 "0.512 [0.301, 0.733]", "live": {"mean_score": {"value": 0.5, "ci95": [0.3, 0.7]}}})
    for r in rows:
        r["rescored"] = r.get("rescored", "reproduces (5 episodes, largest difference 3.1e-07: floating point)")
        r["floor"] = {"x_floor": 1.7}
    record = {"rows": rows, "rate_hz": 10.0, "episodes": 5, "choice": choice(rows, 10.0, "AMD EPYC"),
              "timing": {"rounds": 10, "calls_per_round": 10, "warm_calls": 3, "threads": 2,
                         "cpu_contention": {"other_cpus": 0.0}},
              "hardware": {"cpu_model": "AMD EPYC", "cpu_count": 2, "cpu_flags": ["avx2", "avx512f"]},
              "versions": {"torch": "2.13.0"}, "git_commit": "abc", "root": str(ROOT), "video": None}
    html = Path(write_page(record, tmp_path)["html"])
    m = check.layout(check.chromium(), html)
    assert m["figures"] and not check.problems(m), check.problems(m)
