"""What an approximate inference tier costs in accuracy: `bcbench tiers RUN_DIR`.

For a trained run, each mode (bcbench.evaluation.backends.MODES) is compared with the torch fast form (exact, the
default) in two ways:
- chunk deviation: the largest difference, in pixels of the 512 px world, between its chunk and the
  fast form's on the same recorded observations (validation-split windows, the same noise);
- score: the same test seeds evaluated in both modes; the per-seed differences get a 95% paired-bootstrap
  interval. A tier whose interval lies wholly below zero is marked "significantly worse".
Exact tiers show deviations of float rounding (< 0.03 px); a stochastic policy's samples can still part
ways where its noise or bin choice is sensitive, which the score comparison then judges.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.evaluation.backends import apply_mode, dataset_observations, run_data_split
from bcbench.evaluation.evaluate import EvalConfig, evaluate
from bcbench.policies.checkpoint import configure_runner, load_runner
from bcbench.policies.learned import PolicyRunner
from bcbench.stats import fmt_estimate, paired_bootstrap
from bcbench.tasks import task_of
from bcbench.utils.io import atomic_path, write_json
from bcbench.utils.system import provenance

BASE = "fast"


def chunk_deviation(runner: PolicyRunner, modes: list[str],
                    observations: list[dict[str, torch.Tensor]]) -> dict[str, float]:
    """Largest |chunk - fast chunk| in pixels per mode over `observations` (normalised, batch 1 each)."""
    chunks: dict[str, np.ndarray] = {}
    for mode in [BASE, *modes]:
        apply_mode(runner, mode)
        runner.model.reset_noise(0)  # the same noise stream in every mode
        with torch.inference_mode():
            out = [runner.normalizer.unnormalize("action", runner.model.predict_action_chunk(o).float())
                   for o in observations]
        chunks[mode] = torch.cat(out).numpy()
    return {m: float(np.abs(chunks[m] - chunks[BASE]).max()) for m in modes}


def paired(base: dict[str, Any], other: dict[str, Any]) -> dict[str, Any]:
    """Mean per-seed score difference (other - base) with its 95% paired-bootstrap interval."""
    def by_seed(r: dict[str, Any]) -> dict[int, float]:
        return {e["seed"]: e["score"] for e in r["episodes"]}

    est, lo, hi, n = paired_bootstrap(by_seed(other), [by_seed(base)])
    return {"n": n, "value": est, "ci95": [lo, hi], "significantly_worse": hi < 0}


def run_tiers(run_dir: str | Path, modes: list[str], episodes: int, sampler: str | None, steps: int | None,
              out: Path, seed_start: int = 100_000, observations: int = 100, progress: bool = True) -> dict[str, Any]:
    runner = load_runner(run_dir)
    configure_runner(runner, sampler, steps)
    obs = dataset_observations(runner.model, "val", observations, seed=1, data_split=run_data_split(run_dir))
    deviation = chunk_deviation(runner, modes, obs)
    evals = {}
    for mode in [BASE, *modes]:
        apply_mode(runner, mode)
        cfg = EvalConfig(episodes=episodes, seed_start=seed_start, task=task_of(runner).name)
        evals[mode] = evaluate(runner, cfg, out / f"eval-{mode}",
                               progress=progress)
    rows = [{"mode": m, "max_deviation_px": deviation.get(m, 0.0), "score": evals[m]["summary"]["mean_score"],
             "paired_vs_fast": paired(evals[BASE], evals[m]) if m != BASE else None} for m in [BASE, *modes]]
    record = {"type": "tiers", "run_dir": str(run_dir), "policy": runner.describe(), "episodes": episodes,
              "seed_start": seed_start, "observations": len(obs), "rows": rows, **provenance("cpu")}
    write_json(out / "tiers.json", record)
    with atomic_path(out / "tiers.md") as tmp:
        tmp.write_text(tiers_table(record) + "\n")
    return record


def tiers_table(record: dict[str, Any]) -> str:
    lines = [f"Accuracy of each inference mode against torch fast (exact) - {record['policy']['name']}, "
             f"{record['policy'].get('sampler', '')}{record['policy'].get('steps', '')}; deviation over "
             f"{record['observations']} validation observations, score over {record['episodes']} "
             f"{'validation' if record.get('seed_start', 100_000) >= 200_000 else 'test'} seeds from "
             f"{record.get('seed_start', 100_000)}",
             "", "| mode | max chunk deviation (px) | mean score [95% CI] | paired difference vs fast [95% CI] | |",
             "|---|---|---|---|---|"]
    for r in record["rows"]:
        p = r["paired_vs_fast"]
        diff = "-" if p is None else f"{p['value']:+.3f} [{p['ci95'][0]:+.3f}, {p['ci95'][1]:+.3f}]"
        flag = "significantly worse" if p and p["significantly_worse"] else ""
        lines.append(f"| {r['mode']} | {r['max_deviation_px']:.4f} | {fmt_estimate(r['score'])} | {diff} | {flag} |")
    return "\n".join(lines)
