"""How to run a training, as opposed to what to train (the policy config): torch-free, so that the command line
reads each option's default and help from here."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bcbench.errors import BCBenchError


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
    demos: int | None = None
    """train on only the first N episodes (by index) of the training split, the validation split unchanged: the
    demonstration-count axis, nested (the 10 are among the 50), default all"""
    eval_every: int | None = None
    """closed-loop rollouts every this many optimiser steps (and at the end): the learning curve"""
    eval_episodes: int = 20
    """episodes per periodic rollout, on validation seeds 200000+ (never the test seeds 100000+)"""
    progress: bool = True
    """show a progress bar"""
    callbacks: tuple[Callable[[Any], None], ...] = ()
    """called with the `Run` after every optimiser step, in order: the extension point for code that watches or
    stops training from outside (a custom display, an experiment inspecting the model, the resume tests)"""

    def __post_init__(self) -> None:
        if self.max_minutes is not None and not self.max_minutes > 0:
            raise BCBenchError(f"--max-minutes must be > 0, got {self.max_minutes}")
        if self.eval_every is not None and self.eval_every < 1:
            raise BCBenchError(f"--eval-every must be >= 1, got {self.eval_every}")
        if self.demos is not None and self.demos < 1:
            raise BCBenchError(f"--demos must be >= 1, got {self.demos}")
        if self.eval_episodes < 1:
            raise BCBenchError(f"--eval-episodes must be >= 1, got {self.eval_episodes}")
