"""The report's first table, "which policy for my control loop", on the committed CPU study."""

from __future__ import annotations

from pathlib import Path

from bcbench.analysis.choose import control_loop_rows
from bcbench.analysis.results import load_realtime, load_rows

CPU = Path(__file__).resolve().parents[1] / "results" / "cpu"


def test_one_row_per_run_with_its_swept_setting_and_safe_rate():
    rows = load_rows(CPU, None, 0.05)
    table = {r[0]: r for r in control_loop_rows(rows, load_realtime(CPU), 0.05)}
    assert len(table) == len({r.run_label for r in rows})
    dp = table["Diffusion Policy (cosine)"]
    # the setting swept in real time (DDIM-10, fixed in the study file), not the best score (DDPM-20's 0.743)
    assert dp[1] == "DDIM10" and dp[2].startswith("0.706")
    assert dp[3] == "70.2 (fast)"  # faster than reference (94.4 ms)
    assert dp[4] == "14.3 Hz (blocking, up to d = 1)"  # 1 step / 70.2 ms
    assert table["BCT"][4].startswith("none shown")  # d = 1 is not shown within the margin
    assert table["Diffusion Policy (linear betas)"][1] == "DDIM10" and table["scripted"][4] == "not swept"


def test_times_of_one_interleaved_run_replace_each_runs_own():
    """Where the folder holds interleaved timings of several modes taken in the same rounds (one run_id), a policy's
    fastest exact mode and its control rate come from them; single-mode files of separate runs are not mixed."""
    from bcbench.analysis.fewstep import one_interleaved_run

    rows = load_rows(CPU, None, 0.05)
    run = {"rounds": 10, "run_id": "r1"}
    paired = {"reference": {**run, "mode": "reference", "median_ms": {"ddim10": 60.0, "bct": 6.0}},
              "openvino-fp32": {**run, "mode": "openvino-fp32", "median_ms": {"ddim10": 25.0, "bct": 4.0}},
              "fast": {**run, "mode": "fast", "run_id": "r0", "median_ms": {"ddim10": 20.0}}}  # another run
    assert sorted(one_interleaved_run(paired)) == ["openvino-fp32", "reference"]
    table = {r[0]: r for r in control_loop_rows(rows, load_realtime(CPU), 0.05, paired)}
    dp = table["Diffusion Policy (cosine)"]
    assert dp[3] == "25.0 (openvino-fp32, interleaved)"  # not the other run's 20.0, nor its own 70.2 (fast)
    assert dp[4] == "40.0 Hz (blocking, up to d = 1)"  # 1 step / 25 ms
    assert table["BCT"][3] == "4.0 (openvino-fp32, interleaved)"
    own = {r[0]: r for r in control_loop_rows(rows, load_realtime(CPU), 0.05)}
    assert table["CNN-MLP"][3] == own["CNN-MLP"][3]  # not timed in the run: its own record
    legacy = {m: {k: v for k, v in t.items() if k != "run_id"} for m, t in paired.items()}
    assert one_interleaved_run(legacy) == {}  # single-mode files without a run id: each run's own record
