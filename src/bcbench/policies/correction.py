"""A2C2's correction head (Sendai, Alvarez, Matsushima, Matsuo, Iwasawa 2025, "Leave No Observation Behind: Real-time
Correction for VLA Action Chunks", arXiv 2509.23224), on a frozen bcbench base policy.

A chunk executes open loop: under a delay of d steps its actions were planned from an observation d or more steps
old. The head restores some closed-loop reaction: every control step it reads the newest observation (through the
base's own image encoder, frozen), the action the executing chunk planned for this step, the chunk's age (steps
since its observation) and the action's index in the chunk, and returns a residual added to that action:

    a_exec = a_plan + r_phi(f(o_now), a_plan, age / A, index / Tp)        r_phi an MLP, its last layer zero at start

so an untrained head executes the base's actions exactly (tested). The base is never trained: its weights are not
the head's parameters, not in its checkpoint, and its encoder's output is taken without gradient.

Training (`bcbench train --policy correction --set base=RUN_DIR`, the flat loop): each sample is a window of
obs_horizon + A frames; a chunk start t0 (the window's current step), an age a ~ uniform{0..A}, one of K chunks
the base samples from the observation at t0 (`plan_draws`; with its sampler at `base_sampler` / `base_steps`),
the head's input the observation at t0 + a and that chunk's action for t0 + a, loss the squared error of a_exec
against the target: A2C2's, the demonstration's action at t0 + a (`target = demo`), or the base's own action from
the observation at t0 + a (`fresh`: the chunk it would plan there with no delay, same draw) or the action sync
execution would run there (`sync`: the chunk planned a mod action_horizon steps before). The demonstration's own
chunk at t0 cannot stand in for the base's plan: its action for t0 + a *is* the target, so the residual would be
zero. The windows come from the demonstrations or, with `rollouts`, from the base's own recorded episodes
(`bcbench eval --record`), which show the chunk errors it makes off its training data. The base is frozen and its
encoder runs in eval mode, so every chunk and every frame's features are fixed functions of the data: each is
computed once (in fixed blocks of steps, so a resumed run rebuilds them bit for bit) and kept. Windows start at
most obs_horizon - 1 steps before an episode, as the base's do, so that frame 1 + a is the step index 1 + a plans
for.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn

from bcbench.data.normalizer import MinMaxNormalizer
from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.data.rollouts import load_rollouts, rollout_attrs
from bcbench.data.sequence import SequenceDataset, frames
from bcbench.errors import BCBenchError
from bcbench.interface import ChunkPolicy, Observation
from bcbench.policies.config import OptimConfig, PolicyConfig, cpu_profile, pick_preset
from bcbench.policies.encoders import FrameFeatures
from bcbench.policies.learned import BCPolicy, PolicyRunner

CACHE_BLOCK = 128  # buffer steps computed together on a cache miss (CorrectionPolicy._block)


def _head_optim() -> OptimConfig:
    return OptimConfig(optimizer="adamw", lr=1e-3, weight_decay=1e-6, schedule="cosine", warmup_steps=100, epochs=2,
                       batch_size=64, checkpoint_every=200)


@dataclass
class CorrectionConfig(PolicyConfig):
    """A2C2's correction head on a frozen base run (module docstring)."""

    base: str = ""
    """the frozen base policy's run folder (a trained diffusion, flow, bct or bet run, or a published model);
    required"""
    base_sampler: str | None = None
    """the base's sampler while the head trains (None: the base's own); give the one it will run with (e.g. ddim)"""
    base_steps: int | None = None
    """the base's sampling steps while the head trains (None: its own; DP's default is 100 DDPM steps)"""
    max_age: int = 14
    """A: the oldest chunk age trained, in control steps (at most pred_horizon - obs_horizon, the last action of a
    chunk)"""
    hidden: tuple[int, ...] = (256, 256)
    """widths of the MLP's hidden layers (Mish)"""
    head_frames: int | None = None
    """how many of the newest observation frames the head reads (None: obs_horizon, the base's). 1 shows it no
    motion: from two frames and two positions it can predict the next action by continuing the current motion, an
    accurate open-loop guess that feeds on itself closed loop (the copycat problem of behaviour cloning from
    observation histories, Wen et al. 2020)"""
    plan_draws: int = 4
    """K: the base's chunks kept per chunk start, draw k from the noise seeded by (the head's seed, the episode, k),
    so within an episode draw k starts every chunk from one noise; a sample takes one of the K at random. The base
    is frozen and its encoder runs in eval mode, so a chunk and a frame's features are fixed functions of the data:
    each is computed once, the first time a batch needs it, and kept (the cost of training is then the K chunks a
    start and one encoder pass a frame, not a base sampling every step)"""
    target: str = "demo"
    """what a_exec is trained towards: `demo`, the demonstration's action at t0 + a (A2C2's), or `fresh`, the base's
    own action for t0 + a from the observation at t0 + a (its chunk index obs_horizon - 1, the same noise draw k):
    what the base would do with no delay, so the head learns to undo the age of its chunk; or `sync`, the action
    sync execution would run at t0 + a: the chunk planned j = a mod action_horizon steps before, at its index
    obs_horizon - 1 + j (so an age within one action horizon is its own target, and an older chunk's target keeps
    the consistency of a chunk, which `fresh`'s one-step replanning gives up)"""
    target_draw: str = "same"
    """which of the K chunks planned where the target's chunk starts (`fresh`, `sync`) gives the target: `same`, the
    stale chunk's own draw k (the same noise: often, not always, the same mode); `nearest`, the draw whose actions
    over the steps both chunks plan are closest to the stale chunk's. A multimodal base (Push-T: around the T on
    either side) plans a later chunk in either mode, and a squared-error head trained towards both learns their mean,
    which is neither; the nearest draw keeps the executing chunk's mode, as inference-time RTC's inpainting does
    (Black, Galliker, Levine 2025, arXiv 2506.07339)"""
    rollouts: str = ""
    """a rollout store of the base's own episodes (`bcbench eval --checkpoint BASE --record FILE.npz`) to train on
    instead of the demonstrations, in the base's units (target `fresh` or `sync`: its actions are not an expert's).
    The base's chunks on its training demonstrations are close to the demonstration itself (it fits them), so
    there its chunk's error, which the head learns to correct, is smaller than on episodes it has not seen"""
    optim: OptimConfig = field(default_factory=_head_optim)

    def __post_init__(self) -> None:
        super().__post_init__()
        self.hidden = tuple(self.hidden)
        if not 0 <= self.max_age <= self.pred_horizon - self.obs_horizon:
            top = self.pred_horizon - self.obs_horizon
            raise BCBenchError(f"max_age must be in 0..pred_horizon - obs_horizon ({top}), got {self.max_age}")
        if not self.hidden or min(self.hidden) < 1:
            raise BCBenchError(f"hidden must list layer widths >= 1, got {self.hidden}")
        if self.target not in ("demo", "fresh", "sync"):
            raise BCBenchError(f"target must be demo, fresh or sync, got {self.target!r}")
        if self.target_draw not in ("same", "nearest"):
            raise BCBenchError(f"target_draw must be same or nearest, got {self.target_draw!r}")
        if self.target_draw == "nearest" and self.target == "demo":
            raise BCBenchError("target_draw=nearest picks among the base's chunks: it needs target=fresh or sync")
        if self.rollouts and self.target == "demo":
            raise BCBenchError("rollouts hold the base's actions, not an expert's: train on them with target=fresh "
                               "or target=sync")
        if self.head_frames is not None and not 1 <= self.head_frames <= self.obs_horizon:
            raise BCBenchError(f"head_frames must be in 1..obs_horizon ({self.obs_horizon}), got {self.head_frames}")
        if self.plan_draws < 1:
            raise BCBenchError(f"plan_draws must be >= 1, got {self.plan_draws}")
        if self.base_steps is not None and self.base_steps < 1:
            raise BCBenchError(f"base_steps must be >= 1, got {self.base_steps}")

    @classmethod
    def preset(cls, name: str) -> CorrectionConfig:
        def quick() -> CorrectionConfig:
            return cls(hidden=(128, 128))

        def cpu() -> CorrectionConfig:
            # not yet chosen on validation seeds: 100 epochs x 256 at lr 1e-3 (Push-T: about 21,800 training windows,
            # 85 steps an epoch, so about 8,500 steps, 2.2 M samples; A2C2's Kinetix head trained about 16 M). The
            # chunks and features are computed once (plan_draws), so the steps after the first epochs are the MLP's
            return cpu_profile(cls(), epochs=100, batch_size=256, lr=1e-3, warmup_steps=100)

        return pick_preset("correction", name, {"quick": quick, "cpu": cpu, "paper": lambda: cls(hidden=(512, 512))})


def sha_digest(sha256: str | None) -> torch.Tensor:
    """A hex sha256 as 32 bytes (zeros when unknown), a buffer the checkpoint keeps."""
    return torch.tensor(list(bytes.fromhex(sha256)) if sha256 else [0] * 32, dtype=torch.uint8)


class CorrectionPolicy(BCPolicy):
    """The head's MLP, with its frozen base held outside the module tree (not a parameter, buffer or submodule)."""

    name = "correction"
    standalone = False  # not a policy of its own: it runs beside its base (--strategy correction)

    def __init__(self, config: CorrectionConfig, base: PolicyRunner | None = None) -> None:
        super().__init__()
        self.config = c = config
        if base is None:
            raise BCBenchError("a correction head is built on its base: --set base=RUN_DIR (a trained run)")
        m = base.model
        if (m.config.obs_horizon, m.config.pred_horizon) != (c.obs_horizon, c.pred_horizon):
            raise BCBenchError(f"the base {c.base} has horizons ({m.config.obs_horizon}, {m.config.pred_horizon}), the "
                               f"head ({c.obs_horizon}, {c.pred_horizon}): set the head's to the base's")
        if not isinstance(getattr(m, "encoder", None), FrameFeatures):
            raise BCBenchError(f"the base {c.base} ({m.name}) has no per-frame image encoder to read features from "
                               "(diffusion, flow, bct and bet have one)")
        if c.base_sampler or c.base_steps:
            if not m.samplers:
                raise BCBenchError(f"base_sampler/base_steps apply to a generative base, not to {m.name}")
            m.set_sampler(c.base_sampler or m.sampler_kind, c.base_steps or m.sampler_steps)
        m.eval().requires_grad_(False)
        self.use_task(m.task)  # the base's task: its shapes
        self._base = (base,)  # a tuple: nn.Module registers no submodule, so nothing of the base trains or is saved
        feat = self.frames * (m.encoder.out_dim + self.state_dim)
        dims = [feat + self.action_dim + 2, *c.hidden]  # features, planned action (A), age, index
        layers: list[nn.Module] = []
        for a, b in itertools.pairwise(dims):
            layers += [nn.Linear(a, b), nn.Mish()]
        last = nn.Linear(dims[-1], self.action_dim)
        nn.init.zeros_(last.weight)  # zero residual until trained: the head starts as the base itself
        nn.init.zeros_(last.bias)
        self.mlp = nn.Sequential(*layers, last)
        self.register_buffer("base_digest", sha_digest(base.info.weights_sha256))  # which base weights it learned on
        self._data: tuple[Any, ...] | None = None  # the demonstrations, once training attaches them (attach_data)

    @property
    def base(self) -> PolicyRunner:
        return self._base[0]

    def _apply(self, fn: Any, recurse: bool = True) -> Any:  # .to(device) and casts reach the base too
        self.base.model._apply(fn)
        return super()._apply(fn, recurse)

    def trained_on(self) -> str | None:
        """The sha256 of the base weights this head was trained on (from its checkpoint once loaded)."""
        raw = bytes(self.base_digest.cpu().tolist())
        return raw.hex() if any(raw) else None

    def data_window(self) -> dict[str, int | None]:
        """obs_horizon + A frames a window, padded before an episode as the base's windows are (obs_horizon - 1): a
        window starting earlier would repeat the first step in more frames than the base's, and its frame 1 + a
        would no longer be the step its base's chunk index 1 + a plans for."""
        c = self.config
        return {"obs_horizon": c.obs_horizon + c.max_age, "pred_horizon": c.pred_horizon,
                "action_horizon": c.action_horizon, "pad_before": c.obs_horizon - 1, "with_steps": True,
                "with_images": False, "normalizer": self.base.normalizer if c.rollouts else None}

    def training_data(self, path: str | None) -> ReplayBuffer:
        """The demonstrations, or with `rollouts` the base's recorded episodes (checked to be its task's)."""
        if not self.config.rollouts:
            return super().training_data(path)
        attrs, path = rollout_attrs(self.config.rollouts), self.config.rollouts
        if attrs.get("task") != self.task.name:
            raise BCBenchError(f"{path} holds {attrs.get('task')} episodes; the base runs {self.task.name}")
        theirs, ours = attrs.get("policy", {}).get("weights_sha256"), self.base.info.weights_sha256
        if theirs != ours:
            raise BCBenchError(f"{path} holds episodes of other weights ({(theirs or 'unknown')[:12]}) than the "
                               f"base's ({(ours or 'unknown')[:12]}): record the base's own (bcbench eval --record)")
        return load_rollouts(path)

    def attach_data(self, train_ds: SequenceDataset) -> None:
        """Keep the demonstrations (frames read by buffer step) and empty caches sized to them."""
        buf, c, m = train_ds.buffer, self.config, self.base.model
        self._data = (buf, self.base.normalizer)  # a tuple: not module state
        n = buf.n_steps
        self._feats = torch.zeros(n, m.encoder.out_dim)  # (N, F): the base encoder's features of each frame
        self._feats_ok = torch.zeros(n, dtype=torch.bool)
        self._plans = torch.zeros(n, c.plan_draws, c.pred_horizon, self.action_dim)  # (N, K, Tp, A) normalised
        self._plans_ok = torch.zeros(n, c.plan_draws, dtype=torch.bool)

    def _block(self, b: int) -> torch.Tensor:
        """The buffer steps of cache block b. A miss computes its whole block in one batch, so that every value is
        computed in the same batch whatever order training asks for them in (CPU kernels round by batch size):
        a resumed run rebuilds its caches to the same bits."""
        return torch.arange(b * CACHE_BLOCK, min(self._data[0].n_steps, (b + 1) * CACHE_BLOCK))

    def _frames(self, steps: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(frames(self._data[0], steps)).to(self.device)

    def cached_features(self, steps: torch.Tensor) -> torch.Tensor:
        """The base encoder's features of the frames at buffer `steps` (B, To) -> (B, To, F), each computed once."""
        if self._data is None:
            raise BCBenchError("the correction head reads its training frames by step: attach_data(train_ds) first")
        steps = steps.cpu()  # the caches live on the CPU
        for b in torch.unique(steps[~self._feats_ok[steps]] // CACHE_BLOCK).tolist():
            part = self._block(b)  # (M,)
            with torch.no_grad():
                f = self.base.model.encoder(self._frames(part.numpy())[:, None])  # (M, 1, F)
            self._feats[part], self._feats_ok[part] = f[:, 0].float().cpu(), True
        return self._feats[steps].to(self.device)

    def cached_plans(self, t0: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        """The base's chunk from the observation window ending at buffer step t0 (B,), noise draw k (B,): (B, Tp, A)
        normalised, each (step, k) sampled once, from the seed of (the head's seed, t0's episode, k): within an
        episode draw k starts every chunk from the same noise, so a chunk planned later (the fresh target) is the
        one the base would have drawn there with the stale chunk's noise."""
        if self._data is None:
            raise BCBenchError("the correction head reads its training frames by step: attach_data(train_ds) first")
        buf, norm = self._data
        t0, k = t0.cpu(), k.cpu()  # the caches live on the CPU
        miss = ~self._plans_ok[t0, k]
        for b, j in torch.unique(torch.stack([t0[miss] // CACHE_BLOCK, k[miss]], 1), dim=0).tolist():
            part = self._block(b).numpy()  # (M,)
            episode = np.searchsorted(buf.episode_ends, part, side="right")
            first = buf.episode_starts[episode]
            window = np.maximum(part[:, None] + np.arange(1 - self.config.obs_horizon, 1), first[:, None])  # (M, To)
            pos = norm.normalize("agent_pos", buf.state[window, : self.state_dim]).astype(np.float32)  # (M, To, S)
            gens = [torch.Generator(device=self.device).manual_seed(
                int(np.random.SeedSequence([self.config.seed, int(e), j]).generate_state(1, np.uint64)[0] >> 2))
                for e in episode]  # one noise per (episode, draw): a fresh chunk shares its stale chunk's noise
            with torch.no_grad():
                plan = self.base.model.predict_action_chunk({"image": self._frames(window), "generators": gens,
                                                             "agent_pos": torch.from_numpy(pos).to(self.device)})
            self._plans[part, j], self._plans_ok[part, j] = plan.float().cpu(), True
        return self._plans[t0, k].to(self.device)

    def fit_data(self, train_ds: SequenceDataset) -> None:
        """The head reads the base's normalised units: refuse data normalised otherwise (another split or dataset)."""
        if train_ds.normalizer.to_dict() != self.base.normalizer.to_dict():
            raise BCBenchError(f"this run's training split is normalised differently from the base's "
                               f"({self.config.base}): train the head on the base's dataset and split")

    @property
    def device(self) -> torch.device:
        return self.mlp[0].weight.device

    @property
    def frames(self) -> int:
        """The newest observation frames the head reads (head_frames, else obs_horizon)."""
        return self.config.head_frames or self.config.obs_horizon

    def features(self, image: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:
        """The base encoder's features of an observation window's newest `frames`: (B, To, 3, H, W), (B, To, S) ->
        (B, frames (F + S))."""
        n = self.frames
        with torch.no_grad():
            return torch.cat([self.base.model.encoder(image[:, -n:]), agent_pos[:, -n:]], dim=-1).flatten(1).detach()

    def residual(self, feats: torch.Tensor, action: torch.Tensor, age: torch.Tensor, index: torch.Tensor
                 ) -> torch.Tensor:
        """r_phi: feats (B, G), planned action (B, A) normalised, age and index (B,) -> residual (B, A) normalised."""
        c = self.config
        scalars = torch.stack([age.float() / max(1, c.max_age), index.float() / c.pred_horizon], dim=-1)  # (B, A)
        return self.mlp(torch.cat([feats, action, scalars.to(feats.dtype)], dim=-1))

    def terms(self, batch: dict[str, torch.Tensor], age: torch.Tensor, k: torch.Tensor) -> dict[str, torch.Tensor]:
        """One sample's parts at chunk age `age` and noise draw `k` (B,): the head's inputs (feats, planned, index),
        its target, and `real` (0 where t0 + a is past the episode's end and the target is the base's own)."""
        c, steps, pos = self.config, batch["steps"], batch["agent_pos"]  # (B, To + A, ...)
        to, cs = c.obs_horizon, c.obs_horizon - 1
        rows = torch.arange(len(age), device=age.device)
        window = age[:, None] + torch.arange(to - self.frames, to, device=age.device)  # (B, n): frames ending at t0 + a
        feats = torch.cat([self.cached_features(steps[rows[:, None], window]), pos[rows[:, None], window]], dim=-1)
        index = cs + age
        stale = self.cached_plans(steps[:, cs], k)  # (B, Tp, A): the chunk planned at t0, executing at t0 + a
        planned = stale[rows, index]  # (B, A): its action for step t0 + a
        if c.target == "demo":
            target, real = batch["action"][rows, index], torch.ones_like(age, dtype=torch.float)
        else:
            # the base's own action for t0 + a with the same draw, from the observation there (fresh) or from
            # j = a mod action_horizon steps before it (sync); a step past the episode's end (a padded window repeats
            # its last frame) has no observation of its own: left out
            j = age % c.action_horizon if c.target == "sync" else torch.zeros_like(age)
            start = steps[rows, index - j]  # (B,): where the target's chunk is planned, age - j steps after t0
            if c.target_draw == "nearest":
                k = self.nearest_draw(stale, start, age - j)
            target = self.cached_plans(start, k)[rows, cs + j]
            real = (steps[rows, index] - steps[:, cs] == age).float()
        return {"feats": feats.flatten(1), "planned": planned, "index": index, "target": target, "real": real}

    def nearest_draw(self, stale: torch.Tensor, start: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
        """The draw (B,) among the K chunks planned at buffer step `start` (B,) whose actions are closest (mean
        squared, normalised) to the stale chunk's (B, Tp, A) on the steps both plan: the later chunk's index
        obs_horizon - 1 + m is the stale chunk's obs_horizon - 1 + shift + m, for m < pred_horizon - obs_horizon + 1 -
        shift. A shift of 0 (the same start) finds the stale chunk's own draw, at distance 0."""
        cs, tp = self.config.obs_horizon - 1, self.config.pred_horizon
        draws = range(self.config.plan_draws)
        later = torch.stack([self.cached_plans(start, torch.full_like(start, j)) for j in draws], 1)  # (B, K, Tp, A)
        m = torch.arange(tp - cs, device=stale.device)  # (M,)
        keep = (m[None] < (tp - cs - shift)[:, None]).float()  # (B, M): steps both chunks plan
        where = (cs + shift[:, None] + m[None]).clamp(max=tp - 1)  # (B, M): the same steps in the stale chunk
        theirs = stale[torch.arange(len(shift))[:, None], where]  # (B, M, A)
        gap = ((later[:, :, cs:] - theirs[:, None]) ** 2).mean(-1)  # (B, K, M)
        return ((gap * keep[:, None]).sum(-1) / keep.sum(-1, keepdim=True).clamp(min=1.0)).argmin(-1).cpu()

    def compute_loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """The squared error of the corrected action against the target, over the samples with a real target (every
        one for `demo`)."""
        c = self.config
        k = (self.train_draw(batch, torch.rand) * c.plan_draws).long().clamp_(max=c.plan_draws - 1)  # (B,)
        age = (self.train_draw(batch, torch.rand) * (c.max_age + 1)).long().clamp_(max=c.max_age)  # (B,)
        t = self.terms(batch, age, k)
        executed = t["planned"] + self.residual(t["feats"], t["planned"], age, t["index"])
        real = t["real"]
        return (((executed - t["target"]) ** 2).mean(-1) * real).sum() / real.sum().clamp(min=1.0)

    def predict_action_chunk(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        raise BCBenchError("a correction head is not a policy: run its base with --strategy correction "
                           "--correction DIR")


class CorrectionRunner:
    """The head on raw observations and pixel actions, for the controller's per-step hook (a CorrectionHead)."""

    def __init__(self, model: CorrectionPolicy, normalizer: MinMaxNormalizer, run_dir: str,
                 device: str | torch.device = "cpu", weights_sha256: str | None = None) -> None:
        self.model = model.to(device).eval()
        self.normalizer, self.run_dir, self.device = normalizer, run_dir, torch.device(device)
        self.weights_sha256 = weights_sha256  # the head's own weights file (None: untrained, built in memory)

    def base_mismatch(self, policy: ChunkPolicy) -> str | None:
        trained = self.model.trained_on()
        info = getattr(policy, "info", None)
        theirs = getattr(info, "weights_sha256", None)
        if trained is None or theirs != trained:
            return (f"the head {self.run_dir} was trained on the base {self.model.config.base} (weights "
                    f"{(trained or 'unknown')[:12]}), not on this policy (weights {(theirs or 'unknown')[:12]})")
        return None

    @torch.inference_mode()
    def correct(self, obs: Observation, actions: np.ndarray, ages: np.ndarray, indices: np.ndarray) -> np.ndarray:
        prepared = self.model.base.prepare(obs)  # image (B, To, 3, H, W) in [0, 1], agent_pos normalised
        feats = self.model.features(prepared["image"].to(self.device), prepared["agent_pos"].to(self.device))
        planned = torch.as_tensor(np.asarray(actions, dtype=np.float32), device=self.device)  # (B, A) pixels
        ages_t, index_t = torch.as_tensor(ages, device=self.device), torch.as_tensor(indices, device=self.device)
        res = self.model.residual(feats, self.normalizer.normalize("action", planned), ages_t, index_t)
        zero = torch.zeros_like(res)
        # the residual in pixels: exactly 0 for a zero residual, so an untrained head returns the plan bit for bit
        delta = self.normalizer.unnormalize("action", res) - self.normalizer.unnormalize("action", zero)
        return (planned + delta.float()).cpu().numpy()

    def describe(self) -> dict[str, Any]:
        c = self.model.config
        return {"run_dir": self.run_dir, "weights_sha256": self.weights_sha256, "base": c.base,
                "base_weights_sha256": self.model.trained_on(), "target": c.target, "target_draw": c.target_draw,
                "rollouts": c.rollouts,
                "parameters": self.model.num_parameters(), "max_age": c.max_age, "hidden": list(c.hidden)}
