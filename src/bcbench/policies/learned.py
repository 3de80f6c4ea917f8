"""The learned-policy interface and the runner that puts a trained model in the control loop.

A `BCPolicy` is an nn.Module that works entirely in normalised units:
    compute_loss(batch)          batch: image (B, To, 3, H, W) in [0, 1], agent_pos (B, To, S) and
                                 action (B, Tp, A) in [-1, 1]  ->  scalar loss
    predict_action_chunk(obs)    obs: image, agent_pos as above  ->  (B, Tp, A) in [-1, 1]
Stochastic policies (Diffusion Policy, BeT) draw their noise with `BCPolicy.randn` / `generators`: when
the observation carries `generators` (one torch.Generator per row, made by the controller from the
policy seed and the episode seed), row i's noise comes from its own stream only, so an episode's actions
do not depend on which other episodes share its batch; without them one policy-wide stream is used.
Inference graphs: predict_action_chunk runs its networks through `call_graph(name, *tensors)`, where each
name is a method of pure tensors in, tensors out (`graph_inputs` gives examples). That is the one place a
deployment backend plugs in: `bcbench.evaluation.backends` compiles those methods (OpenVINO) and sets `deployed`;
the Python around them (sampling loops, noise, bins) stays the policy's own, so every backend runs the
same inference path.
A `PolicyRunner` wraps one with its normalizer: raw observations in (uint8 frames, agent position in
pixels), a chunk of target positions in pixels out. The chunk starts at the oldest observation (the
training windows' alignment), so the runner's `chunk_start` is obs_horizon - 1.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
from torch import nn

from bcbench.data.normalizer import MinMaxNormalizer
from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.data.sequence import SequenceDataset
from bcbench.errors import BCBenchError
from bcbench.interface import Observation, RunInfo
from bcbench.policies.config import config_to_dict
from bcbench.policies.encoders import count_parameters
from bcbench.policies.guidance import Guide
from bcbench.policies.prefix import Prefix
from bcbench.tasks import Task, get_task


class BCPolicy(nn.Module):
    """Base class: subclasses set `self.config` and implement the two methods."""

    name = "policy"
    samplers: tuple[str, ...] = ()  # sampler kinds `set_sampler` accepts (generative policies); () = none
    config: Any
    generator: torch.Generator | None = None  # inference noise of stochastic policies (DP, BeT)
    noise_seed: int | None = None

    graphs: tuple[str, ...] = ()  # the methods predict_action_chunk calls through call_graph
    loop_graphs: tuple[str, ...] = ()  # those it calls many times per call (a sampler's loop)
    deployed: dict[str, Any] | None = None  # name -> compiled graph (set by bcbench.evaluation.backends), None = torch
    deployment: dict[str, Any] | None = None  # what runs the graphs (backend, precision), for the records
    guidable = False  # predict_action_chunk(obs, guide=...) samples towards a target (Real-Time Chunking)
    guidance_autograd = True  # that guidance takes a backward pass (an exported graph cannot run it)
    encodes_once = False  # obs["samples"] = n: n samples per observation row, the observation encoded once
    standalone = True  # a policy of its own (False: a head run beside a base, e.g. A2C2's correction head)

    def use_task(self, task: Task | None) -> None:
        """Take the shapes of `task` (None: Push-T): `state_dim` proprioception values a frame in, `action_dim` values
        an action out. Called first in every policy's __init__, before its layers are made."""
        self.task = task or get_task()
        self.state_dim, self.action_dim = self.task.state_dim, self.task.action_dim
        size = getattr(self.config, "image_size", self.task.image_size)
        if size != self.task.image_size:
            raise BCBenchError(f"{self.name}'s image_size is {size}, task {self.task.name}'s frames "
                               f"{self.task.image_size}: --set image_size={self.task.image_size}")

    def call_graph(self, name: str, *args: torch.Tensor) -> Any:
        """Run one inference graph: the deployed (compiled) one if a backend is set, else this module's method."""
        if self.deployed is not None:
            return self.deployed[name](*args)
        return getattr(self, name)(*args)

    def example_obs(self, batch: int = 1) -> dict[str, torch.Tensor]:
        """A random normalised observation window: image (B, To, 3, H, W) in [0, 1], agent_pos (B, To, S)."""
        c = self.config
        return {"image": torch.rand(batch, c.obs_horizon, 3, c.image_size, c.image_size),
                "agent_pos": torch.rand(batch, c.obs_horizon, self.state_dim) * 2 - 1}

    def graph_inputs(self, batch: int = 1) -> dict[str, tuple[torch.Tensor, ...]]:
        """Example inputs of every graph (for export); default: graphs of the observation window."""
        obs = self.example_obs(batch)
        return {name: (obs["image"], obs["agent_pos"]) for name in self.graphs}

    def reset_noise(self, seed: int | None = None) -> None:
        """Restart the inference noise stream at `seed` (None: the config's seed) on its next use."""
        self.generator, self.noise_seed = None, seed

    def noise_generator(self, device: torch.device) -> torch.Generator:
        """The inference noise stream, created on `device` at first use (or after reset_noise)."""
        if self.generator is None or self.generator.device != device:
            seed = self.config.seed if self.noise_seed is None else self.noise_seed
            self.generator = torch.Generator(device=device).manual_seed(seed)
        return self.generator

    def generators(self, obs: dict[str, Any], device: torch.device) -> list[torch.Generator] | torch.Generator:
        """Per-row streams of this call (the controller's, one per episode), else the policy-wide stream."""
        gens = obs.get("generators")
        return list(gens) if gens is not None else self.noise_generator(device)

    def randn(self, obs: dict[str, Any], shape: tuple[int, ...], device: torch.device) -> torch.Tensor:
        """Standard normal noise of `shape` = (B, ...): row i from obs["generators"][i] when given.

        Row by row, each of shape (1, ...), exactly as diffusers' `randn_tensor` draws with a list of generators.
        """
        gens = self.generators(obs, device)
        if isinstance(gens, torch.Generator):
            return torch.randn(shape, generator=gens, device=gens.device).to(device)
        if len(gens) != shape[0]:
            raise ValueError(f"{len(gens)} noise generators for a batch of {shape[0]}")
        return torch.cat([torch.randn((1, *shape[1:]), generator=g, device=g.device) for g in gens]).to(device)

    @staticmethod
    def train_draw(batch: dict[str, Any], draw: Any, shape: tuple[int, ...] = ()) -> torch.Tensor:
        """`draw` (torch.randn or torch.rand) of shape (B, *shape) for this batch's rows: drawn for the global
        batch from the step's generator when the loop attached one (bcbench.training.step_noise), so how the
        batch is sharded over processes does not change it; else from the global stream."""
        ref = batch["action"]
        if batch.get("rng") is None:
            return draw((ref.shape[0], *shape), device=ref.device)
        g = batch["rng"]
        return draw((batch["global_batch"], *shape), generator=g, device=g.device)[batch["rows"]].to(ref.device)

    def data_window(self) -> dict[str, int | None]:
        """The training windows' shape, as `make_datasets` keywords (observation frames, actions, action horizon,
        start padding): the config's horizons by default."""
        c = self.config
        return {"obs_horizon": c.obs_horizon, "pred_horizon": c.pred_horizon, "action_horizon": c.action_horizon,
                "pad_before": None}

    def fit_data(self, train_ds: SequenceDataset) -> None:
        """Data-dependent set-up, once before a fresh run's first step (BeT fits its k-means bins); none by default."""

    def training_data(self, path: str | None) -> ReplayBuffer:
        """The buffer training reads: the task's demonstrations (from `path`, else the default place)."""
        return self.task.demonstrations(path)

    def attach_data(self, train_ds: SequenceDataset) -> None:
        """Called at every start of training, fresh or resumed, before the first step (the correction head keeps the
        demonstrations' frames to read by step); nothing by default."""

    def optim_groups(self, weight_decay: float) -> list[dict[str, Any]]:
        """Parameter groups for the optimiser (one group, decay on everything, unless a policy says otherwise)."""
        return [{"params": list(self.parameters()), "weight_decay": weight_decay}]

    def compute_loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        raise NotImplementedError

    def predict_action_chunk(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        raise NotImplementedError

    def num_parameters(self) -> int:
        return count_parameters(self)


class GraphModule(nn.Module):
    """One inference graph of a policy (a method named in `graphs`) as a module, for the exporters (OpenVINO, ONNX)."""

    def __init__(self, policy: BCPolicy, name: str) -> None:
        super().__init__()
        self.policy, self.method = policy, name  # not `graph`: torch's ONNX exporter reads a module's .graph

    def forward(self, *args: torch.Tensor) -> Any:
        return getattr(self.policy, self.method)(*args)


@contextlib.contextmanager
def glue_threads(model: BCPolicy) -> Iterator[None]:
    """One torch thread for the torch work around a deployed policy's graphs (normalisation, a sampler's update).

    Why: when OpenVINO or ONNX Runtime runs the networks with every core, torch's own intra-op workers, woken by
    the glue's few element-wise ops (an image's conversion is big enough to go parallel), spin after each parallel
    region and take those cores from the runtime's threads. On a 2-core Intel Xeon this cost ResNet-50 2.7 ms of
    11.5 a call (8.8 with one torch thread), CNN-MLP 0.4 ms of 1.3. The torch modes keep their threads (they run
    the networks in torch)."""
    if model.deployed is None:
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


class PolicyRunner:
    """Raw observations -> action chunk in world pixels, for the controller and the latency benchmark."""

    def __init__(self, model: BCPolicy, normalizer: MinMaxNormalizer, device: str | torch.device = "cpu",
                 info: RunInfo | None = None) -> None:
        self.model = model.to(device).eval()
        self.normalizer = normalizer
        self.device = torch.device(device)
        cfg = model.config
        self.name = model.name
        self.obs_horizon, self.pred_horizon, self.action_horizon = cfg.obs_horizon, cfg.pred_horizon, cfg.action_horizon
        self.chunk_start = cfg.obs_horizon - 1
        self.task = model.task  # what it was trained on: evaluation checks --task against it
        self.info = info or RunInfo()

    def prepare(self, obs: dict[str, Any]) -> dict[str, Any]:
        image = torch.from_numpy(np.ascontiguousarray(obs["image"])).to(self.device)  # (B, To, H, W, 3) uint8
        image = image.permute(0, 1, 4, 2, 3).float().div_(255.0)  # (B, To, 3, H, W)
        agent_pos = torch.as_tensor(obs["agent_pos"], dtype=torch.float32, device=self.device)  # (B, To, S)
        out: dict[str, Any] = {"image": image, "agent_pos": self.normalizer.normalize("agent_pos", agent_pos)}
        if obs.get("generators") is not None:
            out["generators"] = obs["generators"]  # per-episode noise streams, from the controller
        return out

    # A generative model's sampler seen through the runner, so that the runner is a GenerativePolicy exactly when
    # its model is one (on other models these attributes raise AttributeError, and isinstance says no).
    @property
    def samplers(self) -> tuple[str, ...]:
        return self.model.samplers

    @property
    def sampler_kind(self) -> str:
        return self.model.sampler_kind

    @property
    def sampler_steps(self) -> int:
        return self.model.sampler_steps

    @property
    def sampler_spacing(self) -> str | None:
        return self.model.sampler_spacing

    def set_sampler(self, kind: str, steps: int, spacing: str | None = None) -> None:
        self.model.set_sampler(kind, steps, spacing)

    @property
    def noise_seed(self) -> int:
        """The seed the controller combines with each episode's seed for that episode's noise stream."""
        return int(self.model.config.seed if self.model.noise_seed is None else self.model.noise_seed)

    @torch.inference_mode()
    def predict_action_chunk(self, obs: Observation) -> np.ndarray:
        with glue_threads(self.model):
            chunk = self.model.predict_action_chunk(self.prepare(obs))  # (B, Tp, A) normalised
            return self.normalizer.unnormalize("action", chunk.float()).cpu().numpy()

    def guidance_unavailable(self, jacobian: bool = True) -> str | None:
        """Why Real-Time Chunking's guided sampling cannot run here, or None when it can."""
        if not self.model.guidable:
            return f"{self.name} does not sample its chunk (guided inpainting needs flow or Diffusion Policy)"
        if self.model.deployed is not None and self.model.guidance_autograd and jacobian:
            return ("guided inpainting needs a vector-Jacobian product through the network, which the exported "
                    f"{(self.model.deployment or {}).get('backend', 'runtime')} graph does not compute: use the torch "
                    "modes (fast or reference), or --rtc-no-jacobian")
        return None

    def predict_guided_chunk(self, obs: Observation, target: np.ndarray, weights: np.ndarray,
                             max_guidance: float, jacobian: bool = True) -> np.ndarray:
        """Real-Time Chunking: a chunk inpainted towards `target` (B, Tp, A) pixels with soft mask `weights` (B, Tp)."""
        reason = self.guidance_unavailable(jacobian)
        if reason:
            raise BCBenchError(reason)
        # flow's guidance runs a backward pass, which inference mode forbids; a guidance without one keeps
        # naive's inference mode (no_grad alone cost Diffusion Policy 2 ms of 46 a call, interleaved)
        with (torch.no_grad() if self.model.guidance_autograd and jacobian else torch.inference_mode(),
              glue_threads(self.model)):
            target_t = torch.as_tensor(np.array(target, dtype=np.float32), device=self.device)
            guide = Guide(self.normalizer.normalize("action", target_t),
                          torch.as_tensor(np.array(weights, dtype=np.float32), device=self.device), float(max_guidance),
                          jacobian)
            chunk = self.model.predict_action_chunk(self.prepare(obs), guide=guide)  # (B, Tp, A) normalised
            return self.normalizer.unnormalize("action", chunk.float()).cpu().numpy()

    def prefix_unavailable(self) -> str | None:
        """Why the model cannot continue a clean prefix (`--strategy prefix`), or None when it can."""
        if not getattr(self.model, "delay_conditioned", False):
            trained = getattr(self.model.config, "delay_train", None)
            return (f"{self.name} was trained without delay conditioning" + (f" (delay_train = {trained})" if trained
                    else "") + ": train one with --set delay_train=[LO,HI] (flow or diffusion)")
        return None

    @torch.inference_mode()
    def predict_prefixed_chunk(self, obs: Observation, prefix: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Training-time RTC: a chunk continuing `prefix` (B, Tp, A) pixels where `mask` (B, Tp) is 1."""
        reason = self.prefix_unavailable()
        if reason:
            raise BCBenchError(reason)
        with glue_threads(self.model):
            actions = torch.as_tensor(np.array(prefix, dtype=np.float32), device=self.device)
            given = Prefix(self.normalizer.normalize("action", actions),
                           torch.as_tensor(np.array(mask, dtype=np.float32), device=self.device))
            chunk = self.model.predict_action_chunk(self.prepare(obs), prefix=given)  # (B, Tp, A) normalised
            out = self.normalizer.unnormalize("action", chunk.float()).cpu().numpy()
        # the prefix is what executes: returned exactly as given (not through the normaliser's round trip)
        return np.where(np.asarray(mask)[..., None] > 0, np.asarray(prefix, dtype=np.float32), out)

    @torch.inference_mode()
    def predict_candidates(self, obs: Observation, n: int) -> np.ndarray:
        """n chunks per observation row (B, n, Tp, A), for Bidirectional Decoding. Row r's candidates draw their noise
        one after the other from row r's stream, so n = 1 is exactly predict_action_chunk."""
        with glue_threads(self.model):
            return self._candidates(obs, n)

    def _candidates(self, obs: Observation, n: int) -> np.ndarray:
        prepared = self.prepare(obs)
        rows = prepared["agent_pos"].shape[0]
        if prepared.get("generators") is not None:
            prepared["generators"] = [g for g in prepared["generators"] for _ in range(n)]
        if self.model.encodes_once:
            prepared["samples"] = n  # each observation encoded once, its condition repeated
        else:
            prepared["image"] = prepared["image"].repeat_interleave(n, 0)
            prepared["agent_pos"] = prepared["agent_pos"].repeat_interleave(n, 0)
        chunk = self.model.predict_action_chunk(prepared)  # (B n, Tp, A) normalised
        out = self.normalizer.unnormalize("action", chunk.float()).cpu().numpy()
        return out.reshape(rows, n, *out.shape[1:])

    def describe(self) -> dict[str, Any]:
        # the noise seed is recorded because `--seed` changes a stochastic policy's episodes without changing its
        # config: two records of one checkpoint that differ only in it are replicates, not repeats
        return {"name": self.name, "parameters": self.model.num_parameters(), "noise_seed": self.noise_seed,
                "task": self.task.name, "config": config_to_dict(self.model.config), **self.info.describe()}
