"""One training loop for every policy: seeded, resumable to the exact weights, budgeted, NaN-safe.

Data order is a pure function of (seed, epoch), so a run resumed from step k draws the same batches as
an uninterrupted one; the torch RNG state (noise, augmentation) is checkpointed with the optimiser,
scheduler and EMA. Validation runs under a forked, fixed-seed RNG, so it never perturbs training.
"""

from __future__ import annotations

import copy
import math
import os
import signal
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.checkpoint import build_model, latest_checkpoint, load_state, load_weights, read_run, save_checkpoint
from bcbench.data import MinMaxNormalizer, load_replay_buffer, make_datasets, resolve_dataset
from bcbench.errors import BCBenchError
from bcbench.policies import REGISTRY
from bcbench.policies.config import OptimConfig, config_to_dict, with_overrides
from bcbench.utils.io import append_jsonl, read_json, read_jsonl, write_json, write_jsonl
from bcbench.utils.system import provenance

STOPPED_BY_TIME = "stopped by time: schedule not finished"


@dataclass
class TrainOptions:
    """How to run, as opposed to what to train (that is the policy config)."""

    max_minutes: float | None = None
    """safety stop only (budgets are steps or epochs, in the config): past it training stops at the next step,
    saves, and the run is marked 'stopped by time: schedule not finished'"""
    threads: int | None = None
    """torch intra-op threads (default: torch's choice)"""
    device: str = "auto"
    """auto (cuda when present), cpu or cuda"""
    data: str | None = None
    """dataset path (default: see `bcbench data info`)"""
    val_fraction: float = 0.1
    """share of episodes held out for validation (the study's 90/10)"""
    split_seed: int = 0
    """seed of the episode split"""
    progress: bool = True
    """show a progress bar"""


class EMA:
    """Exponential moving average of weights with Diffusion Policy's warm-up: decay = 1 - (1 + step)^-power."""

    def __init__(self, model: torch.nn.Module, power: float, max_decay: float) -> None:
        self.model = copy.deepcopy(model).eval().requires_grad_(False)
        self.power, self.max_decay = power, max_decay

    def decay(self, step: int) -> float:
        return float(min(self.max_decay, max(0.0, 1.0 - (1.0 + step) ** -self.power)))

    @torch.no_grad()
    def update(self, model: torch.nn.Module, step: int) -> None:
        d = self.decay(step)
        for e, p in zip(self.model.parameters(), model.parameters(), strict=True):
            e.mul_(d).add_(p.detach(), alpha=1.0 - d)
        for e, b in zip(self.model.buffers(), model.buffers(), strict=True):
            e.copy_(b)  # BatchNorm statistics are not averaged (as in Diffusion Policy's EMAModel)


def has_batchnorm(model: torch.nn.Module) -> bool:
    return any(isinstance(m, torch.nn.modules.batchnorm._BatchNorm) for m in model.modules())


@torch.no_grad()
def precise_batchnorm(model: torch.nn.Module, batches: Any) -> None:
    """Recompute BatchNorm running statistics as exact averages over `batches` ("precise BN").

    The momentum estimates kept during training average only the last few batches; these policies turned
    out to be very sensitive to that noise (CNN-MLP's held-out loss in eval mode was 6x its loss with batch
    statistics, and exact averages closed the gap). Weights are untouched; only the BN buffers change.
    """
    bns = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    if not bns:
        return
    momenta = [bn.momentum for bn in bns]
    for bn in bns:
        bn.reset_running_stats()
        bn.momentum = None  # None = cumulative moving average, i.e. the exact mean over the batches seen
    was_training = model.training
    model.train()
    with torch.random.fork_rng():  # augmentation noise here must not shift the training RNG stream
        torch.manual_seed(0)
        for batch in batches:
            model.compute_loss(batch)
    for bn, mom in zip(bns, momenta, strict=True):
        bn.momentum = mom
    model.train(was_training)


def make_optimizer(model: torch.nn.Module, o: OptimConfig) -> torch.optim.Optimizer:
    cls = torch.optim.AdamW if o.optimizer == "adamw" else torch.optim.Adam
    return cls(model.optim_groups(o.weight_decay), lr=o.lr, betas=o.betas, weight_decay=o.weight_decay)


def make_scheduler(opt: torch.optim.Optimizer, o: OptimConfig, total_steps: int) -> Any:
    if o.schedule == "plateau":
        return torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=o.plateau_factor, patience=o.plateau_patience)

    def factor(step: int) -> float:
        if step < o.warmup_steps:
            return (step + 1) / o.warmup_steps
        if o.schedule == "constant":
            return 1.0
        progress = (step - o.warmup_steps) / max(1, total_steps - o.warmup_steps)
        return 0.5 * (1.0 + math.cos(math.pi * min(1.0, progress)))

    return torch.optim.lr_scheduler.LambdaLR(opt, factor)


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise BCBenchError("--device cuda asked for, but torch sees no CUDA device")
    if name not in ("cpu", "cuda"):
        raise BCBenchError(f"--device must be auto, cpu or cuda, got '{name}'")
    return torch.device(name)


def new_run(policy: str, preset: str, overrides: dict[str, Any], out: str | Path | None,
            opts: TrainOptions) -> Path:
    """Create a run directory with its run.json; returns it (training starts with `train_run`)."""
    if policy not in REGISTRY:
        raise BCBenchError(f"unknown policy '{policy}' (registered: {', '.join(sorted(REGISTRY))})")
    config_cls, _ = REGISTRY[policy]
    if not hasattr(config_cls(), "optim"):
        raise BCBenchError(f"policy '{policy}' has nothing to train")
    config = with_overrides(config_cls.preset(preset), overrides)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    run_dir = Path(out) if out else Path("runs") / f"train-{policy}-{preset}-{stamp}"
    if (run_dir / "run.json").exists():
        raise BCBenchError(f"{run_dir} already holds a run; use --resume {run_dir} or another --out")
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / "run.json", {
        "policy": policy, "preset": preset, "config": config_to_dict(config), "overrides": overrides,
        "data_split": {"val_fraction": opts.val_fraction, "split_seed": opts.split_seed},
        "created": datetime.now(UTC).isoformat(timespec="seconds"), **provenance(),
    })
    return run_dir


class Trainer:
    """Trains the model of one run directory, from scratch or from its newest checkpoint."""

    def __init__(self, run_dir: str | Path, opts: TrainOptions) -> None:
        self.run_dir, self.opts = Path(run_dir), opts
        self.run = read_run(self.run_dir)
        if opts.threads:
            torch.set_num_threads(opts.threads)
        self.device = pick_device(opts.device)
        split = self.run.get("data_split", {})
        buf = load_replay_buffer(resolve_dataset(opts.data))
        torch.manual_seed(self.run["config"]["seed"])  # initialisation is part of the seeded run
        self.model = build_model(self.run)
        c = self.model.config
        self.cfg, self.o = c, c.optim
        self.train_ds, self.val_ds, norm = make_datasets(
            buf, split.get("val_fraction", opts.val_fraction), split.get("split_seed", opts.split_seed),
            c.obs_horizon, c.pred_horizon, c.action_horizon)
        if len(self.train_ds) < self.o.batch_size:
            raise BCBenchError(f"only {len(self.train_ds)} training windows for a batch of {self.o.batch_size}")
        self.steps_per_epoch = len(self.train_ds) // self.o.batch_size  # drop_last: every batch is full
        self.total_steps = self.o.epochs * self.steps_per_epoch
        if self.o.max_steps:
            self.total_steps = min(self.total_steps, self.o.max_steps)
        self.model.to(self.device)
        if self.device.type == "cuda":
            self.model.to(memory_format=torch.channels_last)
        self.ema = EMA(self.model, self.o.ema_power, self.o.ema_max_decay) if self.o.ema else None
        self.optimizer = make_optimizer(self.model, self.o)
        self.scheduler = make_scheduler(self.optimizer, self.o, self.total_steps)
        self.step, self.best_val, self.last_val = 0, float("inf"), float("nan")
        self.train_time_before = 0.0  # seconds of training in earlier sessions of this run
        norm_file = self.run_dir / "normalizer.json"
        if norm_file.exists():  # resumed: keep the statistics the weights were trained with
            self.normalizer = MinMaxNormalizer.from_dict(read_json(norm_file))
        else:
            self.normalizer = norm
            write_json(norm_file, norm.to_dict())
        self.train_ds.normalizer = self.val_ds.normalizer = self.normalizer
        self._resume()

    def _resume(self) -> None:
        ckpt = latest_checkpoint(self.run_dir)
        if ckpt is None:
            if hasattr(self.model, "prepare"):  # data-dependent set-up (BeT's k-means), fresh runs only
                self.model.prepare(self.train_ds)
                if self.ema is not None:
                    self.ema.model.load_state_dict(self.model.state_dict())
            return
        load_weights(ckpt, self.model)
        state = load_state(ckpt)
        if self.ema is not None:
            load_weights(ckpt, self.ema.model, ema=True)
        self.optimizer.load_state_dict(state["optimizer"])
        self.scheduler.load_state_dict(state["scheduler"])
        torch.set_rng_state(state["torch_rng"])
        if self.device.type == "cuda" and state.get("cuda_rng") is not None:
            torch.cuda.set_rng_state(state["cuda_rng"])
        self.step, self.best_val = int(state["step"]), float(state.get("best_val", float("inf")))
        self.last_val = float(state.get("last_val", float("nan")))
        self.train_time_before = float(state.get("train_time_s", 0.0))
        # drop metrics logged after the checkpoint: the resumed run logs those steps again
        metrics = self.run_dir / "metrics.jsonl"
        kept = [m for m in read_jsonl(metrics) if m.get("step", 0) <= self.step]
        write_jsonl(metrics, kept)

    def _batch(self, ids: np.ndarray, ds: Any) -> dict[str, torch.Tensor]:
        nb = self.device.type == "cuda"
        return {k: torch.from_numpy(v).to(self.device, non_blocking=nb) for k, v in ds.get_batch(ids).items()}

    def _loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        if self.device.type == "cuda":
            with torch.autocast("cuda", dtype=torch.bfloat16):
                return self.model.compute_loss(batch)
        return self.model.compute_loss(batch)

    PRECISE_BN_BATCHES = 50

    def recalibrate(self) -> None:
        """Precise BN on the model (and the EMA model) from a fixed, seeded set of training batches."""
        if not has_batchnorm(self.model):
            return
        rng = np.random.default_rng([self.cfg.seed, 4242])
        n = min(self.PRECISE_BN_BATCHES, max(1, len(self.train_ds) // self.o.batch_size))
        ids = [rng.integers(0, len(self.train_ds), self.o.batch_size) for _ in range(n)]
        for model in [self.model] + ([self.ema.model] if self.ema is not None else []):
            precise_batchnorm(model, (self._batch(i, self.train_ds) for i in ids))

    @torch.no_grad()
    def validate(self) -> float:
        """Mean loss over every held-out window, with a fixed noise seed (comparable across epochs)."""
        self.model.eval()
        total, n = 0.0, 0
        devices = [self.device.index or 0] if self.device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(12345)
            for s in range(0, len(self.val_ds), self.o.batch_size):
                ids = np.arange(s, min(len(self.val_ds), s + self.o.batch_size))
                total += float(self._loss(self._batch(ids, self.val_ds))) * len(ids)
                n += len(ids)
        self.model.train()
        return total / max(1, n)

    def _save(self) -> Path:
        state = {
            "optimizer": self.optimizer.state_dict(), "scheduler": self.scheduler.state_dict(),
            "torch_rng": torch.get_rng_state(), "best_val": self.best_val, "last_val": self.last_val,
            "cuda_rng": torch.cuda.get_rng_state() if self.device.type == "cuda" else None,
            "train_time_s": self.train_time_before + self._t_train,
        }
        return save_checkpoint(self.run_dir, self.step, self.model, self.ema.model if self.ema else None, state)

    def fit(self) -> dict[str, Any]:
        from tqdm import tqdm

        stop = _StopFlag()
        deadline = time.monotonic() + 60 * self.opts.max_minutes if self.opts.max_minutes else None
        seed, bs = self.cfg.seed, self.o.batch_size
        self.model.train()
        bar = tqdm(total=self.total_steps, initial=self.step, desc=f"train {self.model.name}", unit="step",
                   disable=not self.opts.progress)
        reason, run_loss, run_n, t_train, samples = "finished", 0.0, 0, 0.0, 0
        self._t_train = 0.0
        kill_at = int(os.environ.get("BCBENCH_TEST_KILL_AT_STEP", "0"))  # test hook: SIGKILL after this step
        with stop:
            while self.step < self.total_steps:
                t0 = time.perf_counter()
                epoch, i = divmod(self.step, self.steps_per_epoch)
                perm = np.random.default_rng([seed, epoch]).permutation(len(self.train_ds))
                batch = self._batch(perm[i * bs:(i + 1) * bs], self.train_ds)
                loss = self._loss(batch)
                if not torch.isfinite(loss):
                    last = latest_checkpoint(self.run_dir)
                    raise BCBenchError(f"loss is {loss.item()} at step {self.step + 1} (epoch {epoch}): training "
                                       f"stopped; last good checkpoint: {last or 'none'}")
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                if self.o.grad_clip:
                    torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.o.grad_clip)
                self.optimizer.step()
                if self.o.schedule != "plateau":
                    self.scheduler.step()
                self.step += 1
                if self.ema is not None:
                    self.ema.update(self.model, self.step)
                t_train += time.perf_counter() - t0
                self._t_train = t_train
                samples += bs
                loss_value = loss.item()
                run_loss, run_n = run_loss + loss_value, run_n + 1
                lr = self.optimizer.param_groups[0]["lr"]
                if self.step % self.o.log_every == 0:
                    append_jsonl(self.run_dir / "metrics.jsonl", {"step": self.step, "epoch": self.step /
                                 self.steps_per_epoch, "train_loss": run_loss / run_n, "lr": lr,
                                 "samples_per_s": samples / t_train})
                    run_loss, run_n = 0.0, 0
                if self.step % self.steps_per_epoch == 0:
                    self._end_epoch()
                if self.step % self.o.checkpoint_every == 0 and self.step != self.total_steps:
                    self._save()
                bar.update()
                bar.set_postfix(loss=f"{loss_value:.4f}", lr=f"{lr:.2e}", sps=f"{samples / t_train:.0f}",
                                val=f"{self.last_val:.4f}")
                if kill_at and self.step == kill_at:
                    os.kill(os.getpid(), signal.SIGKILL)
                if stop.requested or (deadline and time.monotonic() > deadline):
                    reason = "interrupted" if stop.requested else STOPPED_BY_TIME
                    break
        bar.close()
        if self.step % self.steps_per_epoch != 0:  # stopped mid-epoch: recalibrate BN and validate now
            self.recalibrate()
            self.last_val = self.validate()
            append_jsonl(self.run_dir / "metrics.jsonl", {"step": self.step, "epoch": self.step /
                         self.steps_per_epoch, "val_loss": self.last_val})
        self._save()  # the final checkpoint, with precise BatchNorm statistics
        return self._summary(reason, samples, t_train)

    def _end_epoch(self) -> None:
        self.recalibrate()
        self.last_val = self.validate()
        self.best_val = min(self.best_val, self.last_val)
        if self.o.schedule == "plateau":
            self.scheduler.step(self.last_val)
        append_jsonl(self.run_dir / "metrics.jsonl", {"step": self.step, "epoch": self.step / self.steps_per_epoch,
                                                      "val_loss": self.last_val})

    def _summary(self, reason: str, samples: int, t_train: float) -> dict[str, Any]:
        summary = {
            "policy": self.model.name, "preset": self.run["preset"], "stopped": reason, "step": self.step,
            "total_steps": self.total_steps, "epochs": self.step / self.steps_per_epoch,
            "parameters": self.model.num_parameters(), "samples_per_s": samples / t_train if t_train else None,
            "train_time_s_this_session": t_train, "train_time_s": self.train_time_before + t_train,
            "val_loss": self.last_val, "best_val_loss": self.best_val,
            "device": str(self.device), "threads": torch.get_num_threads(),
            "train_windows": len(self.train_ds), "val_windows": len(self.val_ds),
        }
        write_json(self.run_dir / "train_summary.json", summary)
        return summary


class _StopFlag:
    """First Ctrl-C asks the loop to stop at the next step boundary and save; a second one aborts."""

    def __init__(self) -> None:
        self.requested = False
        self._old: Any = None

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> _StopFlag:
        try:
            self._old = signal.signal(signal.SIGINT, self._handle)
        except ValueError:  # not the main thread: no graceful stop
            self._old = None
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
