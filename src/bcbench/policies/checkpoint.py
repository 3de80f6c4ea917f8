"""Run directories and checkpoints, written so that a crash at any instant leaves a loadable run.

    RUN_DIR/run.json             policy name, preset, full config, data split, provenance
    RUN_DIR/normalizer.json      min-max statistics of the training split
    RUN_DIR/metrics.jsonl        training and validation metrics, one JSON object a line
    RUN_DIR/checkpoints/step_NNNNNNN/{model.safetensors, ema.safetensors, state.pt}
    RUN_DIR/checkpoints/latest.json   -> the newest complete step directory
    RUN_DIR/train_summary.json   written when a run stops (finished, budget, interrupted)

A checkpoint is written into a temporary directory, renamed into place, and only then is latest.json
(atomically) pointed at it; older step directories are pruned afterwards.
"""

from __future__ import annotations

import pickle
import shutil
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from bcbench.data.normalizer import MinMaxNormalizer
from bcbench.errors import BCBenchError
from bcbench.interface import RunInfo
from bcbench.policies import HEADS, REGISTRY, trainable
from bcbench.policies.config import config_from_dict
from bcbench.policies.correction import CorrectionRunner
from bcbench.policies.learned import PolicyRunner
from bcbench.tasks import get_task
from bcbench.utils.io import read_json, sha256_file, write_json

KEEP = 2  # step directories kept besides the newest


def _weights(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    # safetensors refuses shared or non-contiguous storage; a contiguous CPU copy of each is always safe
    return {k: v.detach().to("cpu").contiguous().clone() for k, v in model.state_dict().items()}


def save_checkpoint(run_dir: Path, step: int, model: torch.nn.Module, ema: torch.nn.Module | None,
                    state: dict[str, Any]) -> Path:
    """Write weights (+ EMA weights) and trainer state for `step`; returns the step directory."""
    ckpt_root = Path(run_dir) / "checkpoints"
    ckpt_root.mkdir(parents=True, exist_ok=True)
    name = f"step_{step:07d}"
    final = ckpt_root / name
    tmp = ckpt_root / f".tmp-{name}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    save_file(_weights(model), str(tmp / "model.safetensors"))
    if ema is not None:
        save_file(_weights(ema), str(tmp / "ema.safetensors"))
    torch.save({**state, "step": step}, tmp / "state.pt")
    if final.exists():
        shutil.rmtree(final)
    tmp.rename(final)
    write_json(ckpt_root / "latest.json", {"step": step, "dir": name})
    steps = sorted(p for p in ckpt_root.glob("step_*") if p.is_dir() and p.name != name)
    for old in steps[: max(0, len(steps) - KEEP)]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def latest_checkpoint(run_dir: Path) -> Path | None:
    pointer = Path(run_dir) / "checkpoints" / "latest.json"
    if not pointer.exists():
        return None
    path = pointer.parent / read_json(pointer)["dir"]
    # a published model (bcbench publish) keeps the inference weights only: ema.safetensors without model.safetensors
    if not ((path / "model.safetensors").exists() or (path / "ema.safetensors").exists()):
        raise BCBenchError(f"{pointer} points at {path}, which is incomplete")
    return path


def weights_file(ckpt: Path, weights: str | None) -> Path:
    """A checkpoint's weights file: `weights` "ema" (the EMA, what evaluation uses), else the raw weights."""
    return Path(ckpt) / ("ema.safetensors" if weights == "ema" else "model.safetensors")


def load_weights(path: Path, model: torch.nn.Module, ema: bool = False) -> None:
    file = weights_file(path, "ema" if ema else "raw")
    try:
        model.load_state_dict(load_file(str(file)))
    except (OSError, RuntimeError) as exc:
        raise BCBenchError(f"cannot load weights from {file}: {exc}") from None


def load_state(path: Path) -> dict[str, Any]:
    """The optimiser, schedule, RNG and loop state of a checkpoint, unpickled with `weights_only=True`: tensors,
    numbers, strings and containers only, so a run folder from someone else cannot run code when resumed."""
    if not (Path(path) / "state.pt").exists():
        raise BCBenchError(f"{path} has no trainer state (a published model holds inference weights only); "
                           "it cannot be resumed")
    try:
        return torch.load(Path(path) / "state.pt", map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise BCBenchError(f"{Path(path) / 'state.pt'} holds more than tensors and plain values (refused: "
                           f"unpickling it could run code): {first}") from None


def read_run(run_dir: str | Path) -> dict[str, Any]:
    """run.json of a run directory, with a clear error when it is not one."""
    run_dir = Path(run_dir)
    meta = run_dir / "run.json"
    if not meta.exists():
        raise BCBenchError(f"{run_dir} is not a bcbench run directory (no run.json)")
    return read_json(meta)


def build_model(run: dict[str, Any]) -> torch.nn.Module:
    name = run["policy"]
    if name not in REGISTRY and name not in HEADS:
        raise BCBenchError(f"run uses policy '{name}', which this bcbench does not know")
    config_cls, policy_cls = trainable(name)
    config = config_from_dict(config_cls, run["config"])
    if name in HEADS:  # a head is built on its frozen base run, loaded as evaluation loads it (EMA weights)
        if not config.base:
            raise BCBenchError(f"a {name} head needs its base run: --set base=RUN_DIR")
        return policy_cls(config, load_runner(config.base))
    return policy_cls(config, get_task(run.get("task")))  # a run from before tasks existed is Push-T's


def load_correction(run_dir: str | Path, device: str = "cpu") -> CorrectionRunner:
    """A2C2's correction head (`--correction RUN_DIR`) from its run's newest checkpoint, on its frozen base."""
    run_dir = Path(run_dir)
    run = read_run(run_dir)
    if run["policy"] not in HEADS:
        raise BCBenchError(f"--correction {run_dir} is a {run['policy']} run, not a correction head "
                           "(bcbench train --policy correction)")
    ckpt = latest_checkpoint(run_dir)
    if ckpt is None:
        raise BCBenchError(f"{run_dir} has no checkpoint yet")
    model = build_model(run)
    weights = "ema" if (ckpt / "ema.safetensors").exists() else "raw"  # the EMA where it kept one, as load_runner
    load_weights(ckpt, model, ema=weights == "ema")
    norm = MinMaxNormalizer.from_dict(read_json(run_dir / "normalizer.json"))
    return CorrectionRunner(model, norm, str(run_dir), device, sha256_file(weights_file(ckpt, weights)))


def load_runner(run_dir: str | Path, use_ema: bool = True, device: str = "cpu") -> PolicyRunner:
    """A PolicyRunner (raw obs -> chunk in pixels) from a run's newest checkpoint."""
    run_dir = Path(run_dir)
    run = read_run(run_dir)
    if run["policy"] in HEADS:
        raise BCBenchError(f"{run_dir} is a {run['policy']} head, not a policy: run its base "
                           f"(--checkpoint {run['config'].get('base')}) with --strategy correction "
                           f"--correction {run_dir}")
    ckpt = latest_checkpoint(run_dir)
    if ckpt is None:
        raise BCBenchError(f"{run_dir} has no checkpoint yet")
    model = build_model(run)
    has_ema = (ckpt / "ema.safetensors").exists()
    if not use_ema and not (ckpt / "model.safetensors").exists():
        raise BCBenchError(f"{run_dir} holds the EMA inference weights only (a published model); drop --no-ema")
    weights = "ema" if use_ema and has_ema else "raw"
    load_weights(ckpt, model, ema=weights == "ema")
    norm = MinMaxNormalizer.from_dict(read_json(run_dir / "normalizer.json"))
    info = RunInfo(run_dir=str(run_dir), checkpoint=ckpt.name, weights=weights, preset=run.get("preset"),
                   weights_sha256=sha256_file(weights_file(ckpt, weights)),
                   normalizer_sha256=sha256_file(run_dir / "normalizer.json"))
    return PolicyRunner(model, norm, device, info)


def configure_runner(runner: PolicyRunner, sampler: str | None = None, steps: int | None = None, seed: int = 0,
                     spacing: str | None = None) -> str:
    """Seed a trained runner's inference noise and, for diffusion, pick the sampler, steps and spacing.

    Returns a tag for output names ("ddim10-" for diffusion with trailing spacing, "ddim10-leading-" with
    leading, "" otherwise). Sampler options on a policy without a sampler are an error.
    """
    runner.model.reset_noise(seed)  # stochastic policies: the evaluation seed fixes the noise
    if runner.model.samplers:
        if sampler and sampler not in runner.model.samplers:
            raise BCBenchError(f"{runner.name} samples with {' or '.join(runner.model.samplers)}, not '{sampler}'")
        kind, k = sampler or runner.model.sampler_kind, steps or runner.model.sampler_steps
        runner.model.set_sampler(kind, k, spacing)
        spacing = runner.model.sampler_spacing
        runner.info.sampler, runner.info.steps, runner.info.spacing = kind, k, spacing
        return f"{kind}{k}-" + ("" if spacing in (None, "trailing") else f"{spacing}-")
    if sampler or steps or spacing:
        raise BCBenchError(f"--sampler/--steps/--spacing apply to generative policies (diffusion, flow), not to "
                           f"'{runner.name}'")
    return ""
