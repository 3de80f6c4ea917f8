"""One flat training loop for every policy: seeded, resumable to the exact weights, step-budgeted, NaN-safe.

    prepare(run_dir, opts)  builds the model, data, optimiser and schedule of a run directory and resumes
                            from its newest checkpoint (a `Run`);
    train(run_dir, opts)    runs the loop below to the step budget and returns the summary.

Data order is a pure function of (seed, epoch), so a run resumed from step k draws the same batches as an
uninterrupted one; the torch RNG state (noise, augmentation), the optimiser, the schedule, the EMA weights
and a small `TrainState` are checkpointed together. Validation and periodic rollouts run under a forked,
fixed-seed RNG, so they never perturb training. The budget is optimiser steps (epochs or max_steps); the
learning-rate schedule is sized to them, so it always finishes; a wall-clock limit is a safety stop only.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict, dataclass, fields
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from bcbench.data import MinMaxNormalizer, make_datasets
from bcbench.data.sequence import SequenceDataset
from bcbench.errors import BCBenchError
from bcbench.evaluation.evaluate import EvalConfig, run_episodes
from bcbench.policies import trainable
from bcbench.policies.checkpoint import (
    build_model,
    latest_checkpoint,
    load_state,
    load_weights,
    read_run,
    save_checkpoint,
)
from bcbench.policies.config import OptimConfig, config_to_dict, dotted_value, with_overrides
from bcbench.policies.learned import BCPolicy, PolicyRunner
from bcbench.protocol import STOPPED_BY_TIME, VALIDATION_SEED_START
from bcbench.reference import CPU_DEVIATIONS
from bcbench.stats import estimate
from bcbench.tasks import DEFAULT_TASK, get_task
from bcbench.training.options import TrainOptions
from bcbench.training.parts import (
    EMA,
    Distributed,
    Scheduler,
    StopFlag,
    autocast,
    channels_last_convs,
    has_batchnorm,
    keep_freed_memory,
    make_optimizer,
    make_scheduler,
    precise_batchnorm,
    resolve_precision,
    step_noise,
)
from bcbench.utils.device import pick_device
from bcbench.utils.io import append_jsonl, read_json, read_jsonl, write_json, write_jsonl
from bcbench.utils.system import cpu_has_bf16, cpu_record, git_commit, provenance

PRECISE_BN_BATCHES = 50

__all__ = ["EMA", "STOPPED_BY_TIME", "TrainOptions", "TrainState", "new_run", "pick_device", "precise_batchnorm",
           "prepare", "train"]


@dataclass
class TrainState:
    """What the loop changes besides weights, optimiser and RNG; saved with every checkpoint."""

    step: int = 0
    samples: int = 0  # training windows seen
    train_time_s: float = 0.0  # optimiser-step time summed over every session of the run
    best_val: float = float("inf")
    last_val: float = float("nan")

    def state_dict(self) -> dict[str, Any]:
        return asdict(self)

    def load_state_dict(self, d: dict[str, Any]) -> None:
        for f in fields(self):
            if f.name in d:
                setattr(self, f.name, type(getattr(self, f.name))(d[f.name]))


@dataclass
class Run:
    """A run directory made ready to train: model, EMA, optimiser, schedule, data, state."""

    run_dir: Path
    meta: dict[str, Any]  # run.json
    model: BCPolicy
    ema: EMA | None
    optimizer: torch.optim.Optimizer
    scheduler: Scheduler
    train_ds: SequenceDataset
    val_ds: SequenceDataset
    normalizer: MinMaxNormalizer
    device: torch.device
    precision: str  # resolved: fp32 or bf16
    steps_per_epoch: int
    total_steps: int
    state: TrainState
    dist: Distributed  # this process in a torchrun group (world 1 without torchrun)
    loss_fn: torch.nn.Module  # the model's loss as a module: DDP-wrapped with several processes
    malloc_keeps_freed: bool = False  # keep_freed_memory() took effect (CPU training on glibc)

    @property
    def o(self) -> OptimConfig:
        return self.model.config.optim


def new_run(policy: str, preset: str, overrides: dict[str, Any], out: str | Path | None,
            opts: TrainOptions, task: str = DEFAULT_TASK) -> Path:
    """Create a run directory with its run.json (the task, the policy's config, the split); returns it (training
    starts with `train`)."""
    config_cls, _ = trainable(policy)  # a registered policy, or a head trained beside one (policies.HEADS)
    if not hasattr(config_cls(), "optim"):
        raise BCBenchError(f"policy '{policy}' has nothing to train")
    config = with_overrides(config_cls.preset(preset), overrides)
    preset_dict = config_to_dict(config_cls.preset(preset))
    get_task(task).dataset(opts.data)  # a bad --task or --data fails here, before any run folder exists
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    run_dir = Path(out) if out else Path("runs") / f"train-{policy}-{preset}-{stamp}"
    if (run_dir / "run.json").exists():
        raise BCBenchError(f"{run_dir} already holds a run; use --resume {run_dir} or another --out")
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / "run.json", {
        "policy": policy, "task": task, "preset": preset, "config": config_to_dict(config), "overrides": overrides,
        "preset_values": {k: dotted_value(preset_dict, k) for k in overrides},  # what the analysis compares with
        **({"preset_deviations": CPU_DEVIATIONS[policy]} if preset.startswith("cpu") and policy in CPU_DEVIATIONS
           else {}),
        "data_split": {"val_fraction": opts.val_fraction, "split_seed": opts.split_seed,
                       **({"demos": opts.demos} if opts.demos is not None else {})},
        "created": datetime.now(UTC).isoformat(timespec="seconds"), **provenance(),
    })
    return run_dir


def discard_new_run(run_dir: str | Path) -> None:
    """Undo `new_run` for a training that failed before its first checkpoint (unreadable data, say): its files go,
    and its folder too where nothing else is in it, so a failed start leaves nothing that looks like a run."""
    run_dir = Path(run_dir)
    metrics = run_dir / "metrics.jsonl"
    if (run_dir / "checkpoints").exists() or (metrics.exists() and metrics.stat().st_size > 0):
        return  # it trained (a NaN stop or a failed rollout later on): what it logged is kept
    for name in ("run.json", "normalizer.json", "metrics.jsonl", "train_summary.json"):
        (run_dir / name).unlink(missing_ok=True)
    if run_dir.is_dir() and not any(run_dir.iterdir()):
        run_dir.rmdir()


def prepare(run_dir: str | Path, opts: TrainOptions) -> Run:
    """Everything a run needs to train, resumed from its newest checkpoint when it has one."""
    run_dir = Path(run_dir)
    meta = read_run(run_dir)
    if opts.threads:
        torch.set_num_threads(opts.threads)
    device = pick_device(opts.device)
    keeps_freed = device.type == "cpu" and keep_freed_memory()  # before the big tensors
    split = meta.get("data_split", {})
    torch.manual_seed(meta["config"]["seed"])  # initialisation is part of the seeded run
    model = build_model(meta)
    buf = model.training_data(opts.data)
    o = model.config.optim
    if opts.eval_every and not model.standalone:
        raise BCBenchError(f"--eval-every rolls out a policy; a {model.name} head runs beside its base: score it with "
                           "bcbench realtime --strategy correction")
    train_ds, val_ds, norm = make_datasets(buf, split.get("val_fraction", opts.val_fraction),
                                           split.get("split_seed", opts.split_seed), state_dim=model.state_dim,
                                           demos=split.get("demos"), **model.data_window())
    if len(train_ds) < o.batch_size:
        raise BCBenchError(f"only {len(train_ds)} training windows for a batch of {o.batch_size}")
    steps_per_epoch = len(train_ds) // o.batch_size  # drop_last: every batch is full
    total_steps = min(o.epochs * steps_per_epoch, o.max_steps or math.inf)
    if o.max_steps and o.max_steps > total_steps:  # a budget that silently never binds is how a study arm gets lost
        print(f"note: {o.epochs} epochs of {steps_per_epoch} steps end training at step {total_steps}, before "
              f"max_steps {o.max_steps}; raise optim.epochs to reach it", file=sys.stderr)
    if o.schedule == "plateau" and o.val_every and o.val_every >= total_steps:
        print(f"note: val_every {o.val_every} >= the {total_steps} steps of training: the plateau schedule never "
              "steps (its rate stays at lr)", file=sys.stderr)
    # channels_last: the 2-D convolutions of the image encoders run on oneDNN's NHWC kernels (and tensor cores)
    channels_last_convs(model.to(device))
    ema = EMA(model, o.ema_power, o.ema_max_decay) if o.ema else None
    optimizer = make_optimizer(model, o)
    dist = Distributed(device)
    r = Run(run_dir, meta, model, ema, optimizer, make_scheduler(optimizer, o, total_steps), train_ds, val_ds, norm,
            device, _run_precision(run_dir, o.precision, device), steps_per_epoch, int(total_steps), TrainState(), dist,
            dist.wrap(model), keeps_freed)
    norm_file = run_dir / "normalizer.json"
    if norm_file.exists():  # resumed: keep the statistics the weights were trained with
        r.normalizer = MinMaxNormalizer.from_dict(read_json(norm_file))
    elif dist.main:
        write_json(norm_file, norm.to_dict())
    train_ds.normalizer = val_ds.normalizer = r.normalizer
    _resume(r)
    return r


def _run_precision(run_dir: Path, requested: str, device: torch.device) -> str:
    """The precision is resolved once, at a run's first training segment, and kept when the run resumes on
    another machine: `auto` must not switch a half-trained run between bf16 and fp32 (a segment on a CPU
    without native bf16 then says so in segments.jsonl instead of silently changing numerics)."""
    first = next(iter(read_jsonl(run_dir / "segments.jsonl")), None) if (run_dir / "segments.jsonl").exists() else None
    return first["precision"] if first else resolve_precision(requested, device)


def _log_segment(r: Run) -> None:
    """One line per training session of the run: where it ran (CPU model and flags) and at which precision."""
    cuda = r.device.type == "cuda"
    native = r.precision == "fp32" or (torch.cuda.is_bf16_supported() if cuda else cpu_has_bf16())
    where = "GPU (before Ampere)" if cuda else "CPU (no AVX512-BF16 or AMX)"
    append_jsonl(r.run_dir / "segments.jsonl", {
        "start_step": r.state.step, "started": datetime.now(UTC).isoformat(timespec="seconds"),
        "precision": r.precision, "precision_requested": r.o.precision, "precision_native": native,
        **({} if native else {"note": f"bf16 autocast is emulated on this {where}: slower"}),
        "device": str(r.device), "gpu": torch.cuda.get_device_name(r.device) if cuda else None, **cpu_record(),
        "threads": torch.get_num_threads(), "git_commit": git_commit()})


def _resume(r: Run) -> None:
    ckpt = latest_checkpoint(r.run_dir)
    r.model.attach_data(r.train_ds)
    if ckpt is None:
        r.model.fit_data(r.train_ds)  # data-dependent set-up (BeT's k-means), fresh runs only
        if r.ema is not None:  # the EMA copy was made before it
            r.ema.model.load_state_dict(r.model.state_dict())
        return
    state = load_state(ckpt)  # first: a folder without trainer state (a published model) is refused in one line
    load_weights(ckpt, r.model)
    if r.ema is not None:
        load_weights(ckpt, r.ema.model, ema=True)
    r.optimizer.load_state_dict(state["optimizer"])
    r.scheduler.load_state_dict(state["scheduler"])
    torch.set_rng_state(state["torch_rng"])
    if r.device.type == "cuda" and state.get("cuda_rng") is not None:
        torch.cuda.set_rng_state(state["cuda_rng"])
    r.state.load_state_dict(state.get("train_state", {**state, "samples": int(state["step"]) * r.o.batch_size}))
    # drop metrics logged after the checkpoint: the resumed run logs those steps again
    metrics = r.run_dir / "metrics.jsonl"
    write_jsonl(metrics, [m for m in read_jsonl(metrics) if m.get("step", 0) <= r.state.step])


def _batch(r: Run, ids: np.ndarray, ds: SequenceDataset) -> dict[str, torch.Tensor]:
    nb = r.device.type == "cuda"
    return {k: torch.from_numpy(v).to(r.device, non_blocking=nb) for k, v in ds.get_batch(ids).items()}


def recalibrate(r: Run) -> None:
    """Precise BN on the model (and the EMA model) from a fixed, seeded set of training batches."""
    if not has_batchnorm(r.model):
        return
    rng = np.random.default_rng([r.model.config.seed, 4242])
    n = min(PRECISE_BN_BATCHES, max(1, len(r.train_ds) // r.o.batch_size))
    ids = [rng.integers(0, len(r.train_ds), r.o.batch_size) for _ in range(n)]
    for model in [r.model] + ([r.ema.model] if r.ema is not None else []):
        with autocast(r.device, r.precision):
            precise_batchnorm(model, (_batch(r, i, r.train_ds) for i in ids))


@torch.no_grad()
def validate(r: Run) -> float:
    """Mean loss over every held-out window, with a fixed noise seed (comparable across epochs)."""
    r.model.eval()
    total, n = 0.0, 0
    devices = [r.device.index or 0] if r.device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices), autocast(r.device, r.precision):
        torch.manual_seed(12345)
        for s in range(0, len(r.val_ds), r.o.batch_size):
            ids = np.arange(s, min(len(r.val_ds), s + r.o.batch_size))
            total += float(r.model.compute_loss(_batch(r, ids, r.val_ds))) * len(ids)
            n += len(ids)
    r.model.train()
    return total / max(1, n)


def rollout_score(r: Run, episodes: int) -> dict[str, Any]:
    """Closed-loop score of the weights evaluated at test time (EMA if kept) on validation seeds 200000+."""
    model = r.ema.model if r.ema is not None else r.model
    runner = PolicyRunner(model, r.normalizer, r.device)
    if model.samplers:  # learning curves sample with 10 steps: cheap, and close to the best
        kind, steps, spacing = model.sampler_kind, model.sampler_steps, model.sampler_spacing
        model.set_sampler(kind, min(steps, 10))
    model.reset_noise(model.config.seed)
    try:
        with torch.random.fork_rng():
            cfg = EvalConfig(episodes=episodes, seed_start=VALIDATION_SEED_START, task=model.task.name)
            episodes_out, timing = run_episodes(runner, cfg, progress=False)
    finally:
        if model.samplers:
            model.set_sampler(kind, steps, spacing)
        r.model.train()
    scores = np.array([e.score for e in episodes_out])
    return {"eval_score": estimate(scores), "eval_episodes": episodes, "eval_seed_start": VALIDATION_SEED_START,
            "eval_wall_s": timing["wall_time_s"]}


def save(r: Run) -> Path:
    state = {"optimizer": r.optimizer.state_dict(), "scheduler": r.scheduler.state_dict(),
             "torch_rng": torch.get_rng_state(), "train_state": r.state.state_dict(),
             "cuda_rng": torch.cuda.get_rng_state() if r.device.type == "cuda" else None}
    return save_checkpoint(r.run_dir, r.state.step, r.model, r.ema.model if r.ema else None, state)


def _log(r: Run, record: dict[str, Any], t_start: float) -> None:
    base = {"step": r.state.step, "epoch": r.state.step / r.steps_per_epoch, "samples": r.state.samples,
            "train_time_s": round(r.state.train_time_s, 3), "wall_time_s": round(time.monotonic() - t_start, 3)}
    append_jsonl(r.run_dir / "metrics.jsonl", {**base, **record})


def train(run_dir: str | Path, opts: TrainOptions) -> dict[str, Any]:
    """Train the run to its step budget (or the safety stop, or Ctrl-C); returns and writes the summary."""
    r = prepare(run_dir, opts)
    o, state, seed, bs = r.o, r.state, r.model.config.seed, r.o.batch_size
    t_start, deadline = time.monotonic(), None
    if opts.max_minutes:
        deadline = t_start + 60 * opts.max_minutes
    bar = tqdm(total=r.total_steps, initial=state.step, desc=f"train {r.model.name}", unit="step",
               disable=not opts.progress or not r.dist.main)
    reason, run_loss, run_n, samples_session, time_session, perm_epoch, perm = "finished", 0.0, 0, 0, 0.0, -1, None
    val_every = o.val_every or r.steps_per_epoch  # BN recalibration + validation: every epoch unless set
    r.model.train()
    if r.dist.main:
        _log_segment(r)
    with StopFlag() as stop:
        while state.step < r.total_steps:
            t0 = time.perf_counter()
            epoch, i = divmod(state.step, r.steps_per_epoch)
            if epoch != perm_epoch:  # the epoch's order, drawn once per epoch from (seed, epoch)
                perm, perm_epoch = np.random.default_rng([seed, epoch]).permutation(len(r.train_ds)), epoch
            rows = r.dist.shard(bs)  # this process's rows of the global batch (all of them without torchrun)
            batch = step_noise(_batch(r, perm[i * bs:(i + 1) * bs][rows], r.train_ds), seed, state.step, rows, bs)
            with autocast(r.device, r.precision):
                loss = r.loss_fn(batch)
            loss_all = r.dist.mean(loss)  # the global batch's loss
            if not torch.isfinite(loss_all):  # the one host sync per step: a NaN must never reach a checkpoint
                raise BCBenchError(f"loss is {loss_all.item()} at step {state.step + 1} (epoch {epoch}): training "
                                   f"stopped; last good checkpoint: {latest_checkpoint(r.run_dir) or 'none'}")
            r.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if o.grad_clip:
                torch.nn.utils.clip_grad_norm_(r.model.parameters(), o.grad_clip)
            r.optimizer.step()
            if o.schedule != "plateau":
                r.scheduler.step()
            state.step += 1
            state.samples += bs
            if r.ema is not None:
                r.ema.update(r.model, state.step)
            dt = time.perf_counter() - t0
            state.train_time_s += dt
            time_session += dt
            samples_session += bs
            last_loss = loss_all.item()
            run_loss, run_n = run_loss + last_loss, run_n + 1
            lr = r.optimizer.param_groups[0]["lr"]
            if state.step % o.log_every == 0 and r.dist.main:
                _log(r, {"train_loss": run_loss / run_n, "lr": lr, "samples_per_s": samples_session / time_session},
                     t_start)
                run_loss, run_n = 0.0, 0
            if state.step % val_every == 0:
                _end_epoch(r, t_start)
            if opts.eval_every and state.step % opts.eval_every == 0 and state.step != r.total_steps and r.dist.main:
                if o.val_every and state.step % val_every:
                    recalibrate(r)  # a rollout reads BN statistics: exact ones, as it would right after a validation
                _log(r, rollout_score(r, opts.eval_episodes), t_start)
            if state.step % o.checkpoint_every == 0 and state.step != r.total_steps and r.dist.main:
                save(r)
            bar.update()
            bar.set_postfix(loss=f"{last_loss:.4f}", lr=f"{lr:.2e}", sps=f"{samples_session / time_session:.0f}",
                            val=f"{state.last_val:.4f}")
            for callback in opts.callbacks:
                callback(r)
            if stop.requested or (deadline and time.monotonic() > deadline):
                reason = "interrupted" if stop.requested else STOPPED_BY_TIME
                break
    bar.close()
    if state.step % val_every != 0:  # stopped between validations: recalibrate BN and validate now
        _end_epoch(r, t_start, scheduled=False)
    if opts.eval_every and reason == "finished" and r.dist.main:
        _log(r, rollout_score(r, opts.eval_episodes), t_start)  # the learning curve's last point
    summary = {}
    if r.dist.main:
        save(r)  # the final checkpoint, with precise BatchNorm statistics
        summary = _summary(r, reason, samples_session, time_session)
    r.dist.close()
    return summary


def _end_epoch(r: Run, t_start: float, scheduled: bool = True) -> None:
    """BN recalibration and the validation pass; a scheduled one (not training's last, off the cadence) also
    steps the plateau schedule."""
    recalibrate(r)
    r.state.last_val = validate(r)
    r.state.best_val = min(r.state.best_val, r.state.last_val)
    if scheduled and r.o.schedule == "plateau":
        r.scheduler.step(r.state.last_val)
    if r.dist.main:
        _log(r, {"val_loss": r.state.last_val}, t_start)


def _summary(r: Run, reason: str, samples: int, seconds: float) -> dict[str, Any]:
    s = r.state
    summary = {
        "policy": r.model.name, "preset": r.meta["preset"], "stopped": reason, "step": s.step,
        "total_steps": r.total_steps, "epochs": s.step / r.steps_per_epoch, "samples": s.samples,
        "parameters": r.model.num_parameters(), "samples_per_s": samples / seconds if seconds else None,
        "train_time_s_this_session": seconds, "train_time_s": s.train_time_s,
        "val_loss": s.last_val, "best_val_loss": s.best_val, "precision": r.precision,
        "malloc_keeps_freed": r.malloc_keeps_freed, "device": str(r.device), "threads": torch.get_num_threads(),
        "train_windows": len(r.train_ds), "val_windows": len(r.val_ds),
        "segments": read_jsonl(r.run_dir / "segments.jsonl"), **provenance(str(r.device)),
    }
    write_json(r.run_dir / "train_summary.json", summary)
    return summary
