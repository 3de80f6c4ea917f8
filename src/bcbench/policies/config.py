"""Typed configuration shared by the learned policies: optimisation, schedule, EMA, horizons.

Every policy config embeds an `OptimConfig` and validates itself in `__post_init__`; configs round-trip
through JSON (`config_to_dict` / `config_from_dict`) so that each run saves exactly what it trained.
"""

from __future__ import annotations

import copy
import dataclasses
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bcbench.errors import BCBenchError


@dataclass
class OptimConfig:
    optimizer: str = "adam"
    """adam or adamw"""
    lr: float = 1e-4
    """peak learning rate"""
    betas: tuple[float, float] = (0.9, 0.999)
    """Adam betas"""
    weight_decay: float = 0.0
    """decoupled (adamw) or L2 (adam) weight decay"""
    schedule: str = "plateau"
    """plateau (reduce on validation plateau), cosine (with linear warm-up) or constant"""
    warmup_steps: int = 0
    """linear warm-up steps (cosine and constant)"""
    plateau_factor: float = 0.5
    """learning-rate factor when validation loss plateaus"""
    plateau_patience: int = 2
    """validations (one an epoch unless val_every) without improvement before the plateau schedule reduces the rate"""
    epochs: int = 10
    """passes over the training windows: the training budget (with max_steps); the learning-rate schedule is
    sized to the steps that will run, so it always finishes"""
    max_steps: int | None = None
    """stop after this many optimiser steps (overrides epochs when smaller)"""
    batch_size: int = 64
    """windows per optimiser step"""
    precision: str = "auto"
    """forward-pass precision: auto (bf16 autocast where the hardware computes bf16 natively: AVX512-BF16 or
    AMX CPUs, bf16-capable GPUs; fp32 elsewhere), fp32 or bf16; weights and optimiser stay fp32"""
    grad_clip: float | None = None
    """clip the gradient norm to this value"""
    ema: bool = False
    """keep an exponential moving average of the weights and evaluate with it"""
    ema_power: float = 0.75
    """EMA warm-up power (decay = 1 - (1 + step)^-power, Diffusion Policy's EMAModel)"""
    ema_max_decay: float = 0.9999
    """EMA decay ceiling"""
    checkpoint_every: int = 500
    """optimiser steps between checkpoints (one is always written at the end)"""
    log_every: int = 25
    """optimiser steps between metrics.jsonl lines"""
    val_every: int | None = None
    """optimiser steps between validation passes, each after its BatchNorm recalibration (None: at every epoch's
    end); the last step always has one, and a learning-curve rollout between them recalibrates first. Only the
    plateau schedule reads them (its patience then counts validations); under the others the final weights are
    the same bit for bit on CPU in fp32 (tested). Meant for few demonstrations, where an epoch is a handful of
    steps and the pass over every held-out window costs as much as the training"""

    def __post_init__(self) -> None:
        self.betas = tuple(self.betas)  # type: ignore[assignment]  # JSON gives lists
        if self.optimizer not in ("adam", "adamw"):
            raise BCBenchError(f"optimizer must be adam or adamw, got '{self.optimizer}'")
        if self.precision not in ("auto", "fp32", "bf16"):
            raise BCBenchError(f"precision must be auto, fp32 or bf16, got '{self.precision}'")
        if self.schedule not in ("plateau", "cosine", "constant"):
            raise BCBenchError(f"schedule must be plateau, cosine or constant, got '{self.schedule}'")
        if not self.lr > 0 or self.weight_decay < 0:
            raise BCBenchError(f"need lr > 0 and weight_decay >= 0, got {self.lr}, {self.weight_decay}")
        if self.epochs < 1 or self.batch_size < 1 or self.checkpoint_every < 1 or self.log_every < 1:
            raise BCBenchError("epochs, batch_size, checkpoint_every and log_every must be >= 1")
        if self.max_steps is not None and self.max_steps < 1:
            raise BCBenchError(f"max_steps must be >= 1, got {self.max_steps}")
        if not 0 < self.ema_max_decay < 1:
            raise BCBenchError(f"ema_max_decay must be in (0, 1), got {self.ema_max_decay}")
        if self.val_every is not None and (isinstance(self.val_every, bool) or not isinstance(self.val_every, int)
                                           or self.val_every < 1):
            raise BCBenchError(f"val_every must be a whole number >= 1 (or unset: every epoch), got {self.val_every!r}")


@dataclass
class PolicyConfig:
    """Fields every learned policy has."""

    obs_horizon: int = 2
    """observation frames per call (the study's 2)"""
    pred_horizon: int = 16
    """actions per predicted chunk"""
    action_horizon: int = 8
    """actions executed before re-planning"""
    image_size: int = 96
    """side of the square input image"""
    seed: int = 0
    """seed of initialisation, data order and noise"""
    optim: OptimConfig = field(default_factory=OptimConfig)
    """optimisation and schedule"""

    def __post_init__(self) -> None:
        if isinstance(self.optim, dict):
            self.optim = OptimConfig(**self.optim)
        if self.obs_horizon < 1 or self.pred_horizon < 1:
            raise BCBenchError("obs_horizon and pred_horizon must be >= 1")
        if not 1 <= self.action_horizon <= self.pred_horizon - self.obs_horizon + 1:
            raise BCBenchError(f"action_horizon {self.action_horizon} does not fit in pred_horizon "
                               f"{self.pred_horizon} after obs_horizon {self.obs_horizon}")


def pick_preset(policy: str, name: str, presets: dict[str, Callable[[], Any]]) -> Any:
    """A policy's preset by name, from its table of builders (name -> a function returning the config)."""
    if name not in presets:
        raise BCBenchError(f"unknown preset '{name}' for {policy} (choose {', '.join(presets)})")
    return presets[name]()


def config_to_dict(cfg: Any) -> dict[str, Any]:
    return dataclasses.asdict(cfg)


# Fields added after run keys existed, each with the value that does what runs did before it: a config at that
# value leaves the field out of its run key (bcbench.study.spec_runs), so that every earlier run folder still matches.
KEY_NEUTRAL: dict[str, Any] = {"optim.val_every": None}


def key_dict(config: dict[str, Any]) -> dict[str, Any]:
    """A config dict as a run key hashes it: `KEY_NEUTRAL` fields at their neutral value left out."""
    out = copy.deepcopy(config)
    for key, neutral in KEY_NEUTRAL.items():
        found = _field(out, key)
        if found is not None and found[0][found[1]] == neutral:
            del found[0][found[1]]
    return out


def _field(data: dict[str, Any], key: str) -> tuple[dict[str, Any], str] | None:
    """The dict that holds dotted `key`'s last part, and that part; None where the config has no such field."""
    *parents, name = key.split(".")
    node: Any = data
    for p in parents:
        node = node.get(p) if isinstance(node, dict) else None
    return (node, name) if isinstance(node, dict) and name in node else None


CPU_BATCH = 256  # the cpu profile's batch: 2-3x the samples/s of batch 64 on 2 cores with bf16 (benchmarked)


def cpu_profile(quick: Any, epochs: int, batch_size: int = CPU_BATCH, **optim: Any) -> Any:
    """The `cpu` preset: the quick network with the CPU study's recipe (whether it converged is the 2x check's call).

    Batch 256 unless given (bf16 autocast where the CPU has it), the given epochs, and the quick recipe otherwise,
    with optimiser changes passed in `optim` (e.g. a learning rate for the larger batch). First chosen from learning
    curves (each curve flat over its last quarter within 90 minutes on 2 cores); re-chosen on validation seeds by
    the explore studies (issue 30), which the presets' comments name. Checkpoints every ~25,600 samples.
    """
    o = dataclasses.replace(quick.optim, batch_size=batch_size, epochs=epochs,
                            checkpoint_every=100 * CPU_BATCH // batch_size, **optim)
    return dataclasses.replace(quick, optim=o)


# Fields that runs written by earlier versions carry and that no longer mean anything: dropped on load.
# OptimConfig.max_minutes was a wall-clock training budget; budgets are steps now (the safety stop is
# `bcbench train --max-minutes`).
_RETIRED = {("OptimConfig", "max_minutes")}


def config_from_dict(cls: type, data: dict[str, Any]) -> Any:
    """Rebuild a (nested) config dataclass from its dict; unknown keys are an error."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    data = {k: v for k, v in data.items() if (cls.__name__, k) not in _RETIRED}
    unknown = sorted(set(data) - names)
    if unknown:
        raise BCBenchError(f"unknown field(s) for {cls.__name__}: {', '.join(unknown)}")
    kwargs = {}
    for key, value in data.items():
        hint = hints.get(key)
        if dataclasses.is_dataclass(hint) and isinstance(value, dict):
            value = config_from_dict(hint, value)
        elif isinstance(value, list):
            value = tuple(value)
        kwargs[key] = value
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise BCBenchError(f"invalid {cls.__name__}: {exc}") from None


def dotted_value(data: dict[str, Any], key: str) -> Any:
    """The value at a dotted key of a config dict ('optim.lr'), as a JSON file reads it back (tuples as lists)."""
    for part in key.split("."):
        data = data[part]
    return list(data) if isinstance(data, tuple) else data


def with_overrides(cfg: Any, overrides: dict[str, Any]) -> Any:
    """A copy of cfg with dotted-key overrides, e.g. {'optim.epochs': 2, 'hidden': 64}."""
    data = config_to_dict(cfg)
    for key, value in overrides.items():
        if (found := _field(data, key)) is None:
            raise BCBenchError(f"unknown config field '{key}'")
        node, name = found
        node[name] = value
    return config_from_dict(type(cfg), data)
