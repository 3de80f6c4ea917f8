"""Pieces of the training loop that hold no loop state: device, optimiser and schedule, precision, EMA, precise
BatchNorm, Ctrl-C handling, distributed data parallelism."""

from __future__ import annotations

import contextlib
import copy
import ctypes
import math
import os
import signal
from collections.abc import Iterable
from typing import Any

import torch

from bcbench.errors import BCBenchError
from bcbench.policies.config import OptimConfig
from bcbench.utils.system import cpu_has_bf16

# What the loop steps: per optimiser step (LambdaLR), or per validation (ReduceLROnPlateau).
Scheduler = torch.optim.lr_scheduler.LambdaLR | torch.optim.lr_scheduler.ReduceLROnPlateau

PRECISIONS = ("auto", "fp32", "bf16")


def make_optimizer(model: torch.nn.Module, o: OptimConfig) -> torch.optim.Optimizer:
    cls = torch.optim.AdamW if o.optimizer == "adamw" else torch.optim.Adam
    # fused: one kernel over all parameters (measured 17 vs 53 ms per step for DP's cpu network on 2 cores)
    fused = all(p.device.type in ("cpu", "cuda") and p.is_floating_point() for p in model.parameters())
    return cls(model.optim_groups(o.weight_decay), lr=o.lr, betas=o.betas, weight_decay=o.weight_decay,
               fused=fused)


def make_scheduler(opt: torch.optim.Optimizer, o: OptimConfig, total_steps: int) -> Scheduler:
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


def resolve_precision(precision: str, device: torch.device) -> str:
    """auto -> bf16 where the device computes it natively (CUDA with bf16, AVX512-BF16/AMX CPUs), else fp32."""
    if precision not in PRECISIONS:
        raise BCBenchError(f"precision must be one of {', '.join(PRECISIONS)}, got '{precision}'")
    if precision != "auto":
        return precision
    if device.type == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    return "bf16" if cpu_has_bf16() else "fp32"


def autocast(device: torch.device, precision: str) -> contextlib.AbstractContextManager:
    """bf16 autocast for forward passes (weights and optimiser stay fp32), or nothing for fp32."""
    if precision == "bf16":
        return torch.autocast(device.type, dtype=torch.bfloat16)
    return contextlib.nullcontext()


def channels_last_convs(model: torch.nn.Module) -> torch.nn.Module:
    """Store every 2-D convolution's weight channels-last (NHWC kernels on oneDNN and tensor cores)."""
    for m in model.modules():
        if isinstance(m, torch.nn.Conv2d):
            m.to(memory_format=torch.channels_last)
    return model


def keep_freed_memory() -> bool:
    """Make glibc's malloc keep freed memory in the process instead of handing it back to the kernel.

    By default glibc serves large blocks (a batch-256 activation is tens of MB) with mmap and unmaps them when
    freed, so every training step maps them afresh and the kernel zero-fills them page by page. Measured for
    DP's cpu config on 2 cores: 13-30k page faults and 25-130 ms of kernel time a step, 2k and ~20 ms with
    this (about 12% more samples/s, 130 MB more resident memory). No mmap for blocks (M_MMAP_MAX 0) and a
    1 GiB trim threshold; process-wide, for the rest of the process. Returns False where libc is not glibc.
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_max = -1, -4  # glibc's mallopt parameter numbers (malloc.h)
        return bool(libc.mallopt(m_mmap_max, 0)) and bool(libc.mallopt(m_trim_threshold, 1 << 30))
    except (OSError, AttributeError):
        return False


class EMA:
    """Exponential moving average of weights with Diffusion Policy's warm-up: decay = 1 - (1 + step)^-power."""

    def __init__(self, model: torch.nn.Module, power: float, max_decay: float) -> None:
        self.model = copy.deepcopy(model).eval().requires_grad_(False)
        self.power, self.max_decay = power, max_decay
        self._ema_params = list(self.model.parameters())
        self._ema_buffers = list(self.model.buffers())

    def decay(self, step: int) -> float:
        return float(min(self.max_decay, max(0.0, 1.0 - (1.0 + step) ** -self.power)))

    @torch.no_grad()
    def update(self, model: torch.nn.Module, step: int) -> None:
        # one fused pass over all tensors: e <- e + (1 - d)(p - e) = d e + (1 - d) p
        torch._foreach_lerp_(self._ema_params, [p.detach() for p in model.parameters()], 1.0 - self.decay(step))
        if self._ema_buffers:  # BatchNorm statistics are copied, not averaged (as in Diffusion Policy's EMAModel)
            torch._foreach_copy_(self._ema_buffers, list(model.buffers()))


def has_batchnorm(model: torch.nn.Module) -> bool:
    return any(isinstance(m, torch.nn.modules.batchnorm._BatchNorm) for m in model.modules())


@torch.no_grad()
def precise_batchnorm(model: torch.nn.Module, batches: Iterable[dict[str, torch.Tensor]]) -> None:
    """Recompute BatchNorm running statistics as exact averages over `batches` ("precise BN").

    The momentum estimates kept during training average only the last few batches; these policies turned
    out to be very sensitive to that noise in eval mode, and exact averages close the gap. Weights are
    untouched; only the BN buffers change.
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


class StopFlag:
    """First Ctrl-C asks the loop to stop at the next step boundary and save; a second one aborts."""

    def __init__(self) -> None:
        self.requested = False
        self._old: Any = None

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> StopFlag:
        try:
            self._old = signal.signal(signal.SIGINT, self._handle)
        except ValueError:  # not the main thread: no graceful stop
            self._old = None
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


# ---------------------------------------------------------------------- several processes (torchrun)
class Distributed:
    """The process group of a `torchrun --nproc-per-node N bcbench train ...` run (world 1 without torchrun).

    Every process holds the whole model and draws the same epoch permutation; each takes its contiguous
    shard of every global batch, and DistributedDataParallel averages the gradients, so the update equals
    the single-process one on the whole batch (BatchNorm statistics aside: they are per shard, as with any
    DDP). Rank 0 alone writes checkpoints, metrics and rollouts. NCCL on GPUs, gloo on CPUs.
    """

    def __init__(self, device: torch.device) -> None:
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        if self.world > 1 and device.type == "cuda":
            torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))  # one GPU per process
        if self.world > 1 and not torch.distributed.is_initialized():
            torch.distributed.init_process_group("nccl" if device.type == "cuda" else "gloo")

    @property
    def main(self) -> bool:
        return self.rank == 0

    def shard(self, batch_size: int) -> slice:
        """This process's rows of a global batch."""
        if batch_size % self.world:
            raise BCBenchError(f"batch size {batch_size} does not split over {self.world} processes")
        n = batch_size // self.world
        return slice(self.rank * n, (self.rank + 1) * n)

    def wrap(self, model: torch.nn.Module) -> torch.nn.Module:
        """The module whose forward is the loss: DDP-wrapped when there are several processes."""
        loss = _Loss(model)
        return torch.nn.parallel.DistributedDataParallel(loss) if self.world > 1 else loss

    def mean(self, value: torch.Tensor) -> torch.Tensor:
        """The mean over processes (the global batch's loss from the shards' losses)."""
        if self.world == 1:
            return value
        value = value.detach().clone()
        torch.distributed.all_reduce(value)
        return value / self.world

    def close(self) -> None:
        if self.world > 1 and torch.distributed.is_initialized():
            torch.distributed.barrier()
            torch.distributed.destroy_process_group()


class _Loss(torch.nn.Module):
    """policy.compute_loss as a forward(), so DistributedDataParallel sees the forward it synchronises."""

    def __init__(self, policy: torch.nn.Module) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, batch: dict[str, Any]) -> torch.Tensor:
        return self.policy.compute_loss(batch)


def step_noise(batch: dict[str, Any], seed: int, step: int, rows: slice, global_batch: int) -> dict[str, Any]:
    """Attach the step's training randomness to a (shard of a) batch: a generator seeded from (seed, step)
    and this shard's rows of the global batch, so a policy's per-sample draws (BCPolicy.train_randn) do not
    depend on how the batch is split over processes, and a resumed run draws what it would have drawn."""
    device = next(iter(v for v in batch.values() if isinstance(v, torch.Tensor))).device
    gen = torch.Generator(device=device).manual_seed(int(seed) * 1_000_003 + int(step))
    return {**batch, "rng": gen, "rows": torch.arange(global_batch, device=device)[rows],
            "global_batch": global_batch}
