"""Policies from outside bcbench: `--policy module:factory`, plug-ins (the worked example in examples/), and the
contract check that runs before any episode."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bcbench.cli.main import main
from bcbench.errors import BCBenchError
from bcbench.policies.outside import check_contract, outside_policy
from bcbench.study.spec import parse_spec

ROOT = Path(__file__).resolve().parents[1]
GOOD = "tests.fake_policies:good"


@pytest.mark.parametrize("factory, message", [
    ("missing", "lacks describe"),
    ("wrong_shape", r"returned shape \(2, 8, 2\), expected \(2, 16, 2\)"),
    ("wrong_dtype", "returned dtype int64"),
    ("nan", "NaN or infinite"),
    ("raises", "predict_action_chunk raised RuntimeError: the model file is missing"),
    ("factory_raises", "the factory raised ValueError: no such checkpoint"),
    ("nothere", "has no attribute 'nothere'"),
])
def test_each_contract_violation_is_one_line_and_exit_2(factory, message, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["eval", "--policy", f"tests.fake_policies:{factory}", "--episodes", "1", "--out", str(out),
                 "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and err.startswith("bcbench: error:")
    assert pytest.importorskip("re").search(message, err), err
    assert not out.exists()  # nothing written


def test_unknown_module_and_plugin_are_clear():
    with pytest.raises(BCBenchError, match=r"cannot import module 'no_such_pkg\.mod'"):
        outside_policy("no_such_pkg.mod:make")
    with pytest.raises(BCBenchError, match="not an installed plug-in"):
        outside_policy("no-such-plugin")


def test_the_check_accepts_a_good_policy():
    import bcbench

    policy = outside_policy(GOOD, {"x": 100.0})
    check_contract(policy, GOOD)
    assert isinstance(policy, bcbench.ChunkPolicy)  # `import bcbench` exposes the interface (structural)


def test_factory_policy_in_eval_latency_and_realtime(tmp_path, capsys):
    assert main(["eval", "--policy", GOOD, "--policy-arg", "x=300", "--episodes", "2", "--max-steps", "10",
                 "--out", str(tmp_path / "eval"), "--quiet"]) == 0
    rec = json.loads((tmp_path / "eval" / "eval.json").read_text())
    assert rec["policy"] == {"name": "toward", "target": [300, 256.0], "parameters": 0}
    assert main(["latency", "--policy", GOOD, "--quick", "--out", str(tmp_path / "lat")]) == 0
    rows = json.loads((tmp_path / "lat" / "latency.json").read_text())["rows"]
    assert [(r["policy"], r["source"]) for r in rows] == [("toward", GOOD)] and rows[0]["median_ms"] > 0
    assert main(["realtime", "--policy", GOOD, "--delays", "0", "2", "--execution", "async", "--episodes", "2",
                 "--max-steps", "10", "--out", str(tmp_path / "rt"), "--quiet"]) == 0
    sweep = json.loads((tmp_path / "rt" / "realtime-sweep.json").read_text())
    assert set(sweep["settings"]) == {"realtime-sync", "realtime-async-d2"}


def test_a_study_mixes_an_outside_policy_with_built_in_ones(tmp_path):
    from bcbench.analysis.report import write_report
    from bcbench.study import run_study

    spec = parse_spec({"study": {"name": "mix", "episodes": 2, "max_steps": 10, "latency": True,
                                 "latency_min_calls": 2, "latency_min_seconds": 0.0,
                                 "realtime": {"delays": [2], "execution": ["async"], "measured": False}},
                       "run": [{"policy": "scripted", "realtime": True},
                               {"policy": GOOD, "args": {"x": 200.0}, "label": "toward 200", "realtime": True}]})
    run_study(spec, tmp_path / "mix", progress=False)
    report = Path(write_report(tmp_path / "mix")["markdown"]).read_text()
    assert f"toward 200 (outside bcbench: {GOOD})" in report  # in the results and the real-time tables
    assert report.count("(outside bcbench") >= 2
    with pytest.raises(BCBenchError, match="do not apply"):
        parse_spec({"run": [{"policy": GOOD, "eval": [{"sampler": "ddim"}]}]})


def _bcbench(site: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": f"{site}{os.pathsep}{ROOT / 'src'}"}
    return subprocess.run([sys.executable, "-m", "bcbench.cli", *args], capture_output=True, text=True, env=env,
                          timeout=600)


def test_the_example_plugin_installs_lists_evaluates_times_and_runs_real_time(knn_site, synthetic_zarr, tmp_path):
    listed = _bcbench(knn_site, "policies")
    assert listed.returncode == 0 and "knn" in listed.stdout and "bcbench_knn:make_policy" in listed.stdout
    data = ["--policy", "knn", "--policy-arg", f"data={synthetic_zarr}", "--policy-arg", "k=2"]
    ev = _bcbench(knn_site, "eval", *data, "--episodes", "2", "--max-steps", "10", "--out", str(tmp_path / "e"),
                  "--quiet")
    assert ev.returncode == 0, ev.stderr
    assert json.loads((tmp_path / "e" / "eval.json").read_text())["policy"]["k"] == 2
    lat = _bcbench(knn_site, "latency", *data, "--quick", "--out", str(tmp_path / "l"))
    assert lat.returncode == 0, lat.stderr
    rt = _bcbench(knn_site, "realtime", *data, "--delays", "0", "1", "--execution", "async", "--episodes", "2",
                  "--max-steps", "10", "--out", str(tmp_path / "r"), "--quiet")
    assert rt.returncode == 0, rt.stderr and (tmp_path / "r" / "realtime-sweep.json").exists()
