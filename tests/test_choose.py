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
