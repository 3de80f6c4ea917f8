"""Publish a trained run's inference weights as a small model folder a user can run on a fresh clone.

    models/NAME/run.json, normalizer.json             as in the run (policy, preset, config, data split)
    models/NAME/checkpoints/latest.json               -> the one step directory below
    models/NAME/checkpoints/step_NNNNNNN/ema.safetensors   (or model.safetensors for a run without an EMA)
    models/NAME/model.json                            provenance: source run and step, sha256, and the committed
                                                      per-episode file whose scores these weights reproduce

The layout is a run folder with one checkpoint and no trainer state, so every command that takes
`--checkpoint RUN_DIR` (eval, latency, realtime, export, tiers) takes a published model unchanged. Only the weights
that the study evaluated are kept (the EMA where the run has one, fp32 so scores reproduce exactly): no optimiser
state, no pickle, nothing that runs code when loaded.
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path
from typing import Any

from safetensors import safe_open

from bcbench.errors import BCBenchError
from bcbench.policies.checkpoint import latest_checkpoint, read_run, weights_file
from bcbench.utils.io import atomic_dir, read_json, sha256_file, write_json
from bcbench.utils.system import git_commit


def _check_fp32(file: Path) -> int:
    """Number of parameters in `file`; every floating tensor must be fp32 (scores reproduce only at the
    precision they were computed in)."""
    n = 0
    with safe_open(str(file), framework="pt") as f:
        for key in f.keys():  # noqa: SIM118 (a safetensors file handle is not iterable)
            tensor = f.get_slice(key)
            dtype = str(tensor.get_dtype())
            if dtype.startswith(("F", "BF")) and dtype != "F32":
                raise BCBenchError(f"{file}: tensor {key} is {dtype}, not fp32; publish fp32 weights only")
            n += math.prod(tensor.get_shape())
    return n


def _scores_record(scores: Path, run_dir: Path, ckpt: Path, weights: str) -> dict[str, Any]:
    """The evaluation these weights must reproduce, checked to be of this run, this step and these weights."""
    if not scores.is_file():
        raise BCBenchError(f"--scores {scores}: no such file")
    rec = read_json(scores)
    if not isinstance(rec, dict) or rec.get("type") != "evaluation" or not rec.get("episodes"):
        raise BCBenchError(f"--scores {scores} is not a bcbench evaluation with per-episode scores")
    pol = rec.get("policy", {})
    if Path(str(pol.get("run_dir", ""))).name != run_dir.name:
        raise BCBenchError(f"--scores {scores} evaluated {pol.get('run_dir')}, not {run_dir}")
    if pol.get("checkpoint") != ckpt.name or pol.get("weights") != weights:
        raise BCBenchError(f"--scores {scores} evaluated {pol.get('checkpoint')} ({pol.get('weights')} weights); "
                           f"the run's newest is {ckpt.name} ({weights})")
    if (pol.get("deployment") or {}).get("backend", "torch") != "torch":
        raise BCBenchError(f"--scores {scores} was computed with {pol['deployment']['backend']}; publish a torch "
                           "evaluation (the reference a fresh clone reproduces)")
    cfg = rec["eval_config"]
    return {"file": str(scores), "mean_score": rec["summary"]["mean_score"]["value"],
            "episodes": len(rec["episodes"]), "seed_start": cfg["seed_start"], "max_steps": cfg["max_steps"],
            "execution": cfg.get("execution", "sync"), "sampler": pol.get("sampler"), "steps": pol.get("steps"),
            "spacing": pol.get("spacing"), "mode": pol.get("mode"), "git_commit": rec.get("git_commit"),
            "hardware": {k: rec.get("hardware", {}).get(k) for k in ("cpu_model", "cpu_flags", "torch_threads")}}


# The repository's published models: written from a clean tree only, so the commit a model.json names is the code
# that published it (three early folders were written from uncommitted trees and say "-dirty").
MODELS_DIR = Path(__file__).resolve().parents[3] / "models"


def _history(out: Path) -> list[dict[str, Any]]:
    """The weights a folder held before, newest last: a replaced folder keeps what it replaced, so a record that
    names an older sha256 (the DP and flow folders held their first round's weights before) can still be placed."""
    meta = out / "model.json"
    if not meta.is_file():
        return []
    old = read_json(meta)
    entry = {"sha256": (old.get("file") or {}).get("sha256"), "source": old.get("source"),
             "scores": (old.get("scores") or {}).get("file"), "published_at_commit": old.get("published_at_commit")}
    return [*old.get("history", []), entry]


def publish(run_dir: str | Path, out: str | Path, scores: str | Path, force: bool = False) -> dict[str, Any]:
    """Write the model folder `out` from `run_dir`'s newest checkpoint; returns model.json's record.

    `scores` is the committed evaluation (per-episode JSON) of exactly these weights: model.json points at it so
    that a test, or a user, can check on a few episodes that the published weights reproduce it. Into the
    repository's models/ only from a clean tree; a folder replaced with --force keeps the replaced weights' sha256 in
    `history`."""
    run_dir, out = Path(run_dir), Path(out)
    commit = git_commit()
    declared = bool(os.environ.get("BCBENCH_COMMIT"))  # a copied tree's declared commit, not one git checked
    if out.resolve().parent == MODELS_DIR and (commit is None or commit.endswith("-dirty") or declared):
        raise BCBenchError(f"{out} is a published model folder: publish from a clean, committed tree (this one is "
                           f"{commit or 'not a git checkout'}), so its model.json names the code that wrote it")
    run = read_run(run_dir)
    ckpt = latest_checkpoint(run_dir)
    if ckpt is None:
        raise BCBenchError(f"{run_dir} has no checkpoint to publish")
    weights = "ema" if (ckpt / "ema.safetensors").exists() else "raw"
    file = weights_file(ckpt, weights)
    source = _scores_record(Path(scores), run_dir, ckpt, weights)
    if Path(scores).resolve().is_relative_to(Path.cwd()):  # a committed file: recorded relative to the repository
        source["file"] = str(Path(scores).resolve().relative_to(Path.cwd()))
    parameters = _check_fp32(file)
    record = {
        "name": out.name, "policy": run["policy"], "preset": run.get("preset"), "seed": run["config"].get("seed"),
        "parameters": parameters, "weights": weights,
        "source": {"run": run_dir.name, "checkpoint": ckpt.name, "git_commit": run.get("git_commit")},
        "file": {"path": f"checkpoints/{ckpt.name}/{file.name}", "bytes": file.stat().st_size,
                 "sha256": sha256_file(file), "dtype": "fp32"},
        "scores": source, "published_at_commit": commit,
    }
    history = [h for h in (_history(out) if force else []) if h["sha256"] != record["file"]["sha256"]]
    if history:  # the same weights published again add no entry
        record["history"] = history
    with atomic_dir(out, force=force) as staged:
        (staged / "checkpoints" / ckpt.name).mkdir(parents=True)
        shutil.copy2(file, staged / record["file"]["path"])
        for name in ("run.json", "normalizer.json"):
            shutil.copy2(run_dir / name, staged / name)
        write_json(staged / "checkpoints" / "latest.json", {"step": int(ckpt.name.split("_")[1]), "dir": ckpt.name})
        write_json(staged / "model.json", record)
    return record


def verify(model_dir: str | Path) -> dict[str, Any]:
    """model.json of a published folder, after checking its weights file against the recorded sha256."""
    model_dir = Path(model_dir)
    meta = model_dir / "model.json"
    if not meta.is_file():
        raise BCBenchError(f"{model_dir} is not a published bcbench model (no model.json)")
    record = read_json(meta)
    file = model_dir / record["file"]["path"]
    if not file.is_file():
        raise BCBenchError(f"{file} is missing (a clone without Git LFS content, or a partial copy?)")
    if sha256_file(file) != record["file"]["sha256"]:
        raise BCBenchError(f"{file} does not match the sha256 in {meta}")
    return record
