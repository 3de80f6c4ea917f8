"""The public policy interface: what every seam of bcbench (evaluation, controller, latency, real time, tiers,
studies) takes, for the built-in policies and for yours (`bcbench eval --policy my_pkg.my_module:make`).

A `ChunkPolicy` maps a batch of observation windows in environment units to action chunks in environment units,
in the shapes its task states (`bcbench.tasks.Task`: H = image_size, S = state_dim, A = action_dim):

    obs = {"image": uint8 (B, To, H, H, 3), "agent_pos": float32 (B, To, S), the task's proprioception}
    predict_action_chunk(obs) -> float32 (B, pred_horizon, A), actions in the task's units

Push-T: H = 96, S = 2 (agent position in pixels of the 512 world), A = 2 (target agent positions, same units).
A policy made for another task says so with a `task` attribute (its name, e.g. "metaworld/drawer-open"); without
one it is taken to be Push-T's. A trained runner carries its run's task.

`chunk_start` is the chunk index of the action for the current step (0 when the chunk starts now;
obs_horizon - 1 for policies trained on Diffusion Policy's windows, whose chunk starts at the oldest
observation). History, action queues and execution strategies live in `bcbench.evaluation.controller`, never
in a policy. A stochastic policy may also read `obs["generators"]` (one torch.Generator per row, seeded by the
controller from the policy's `noise_seed` and the episode seed) so that an episode's actions do not depend on
which other episodes share its batch.

Optional parts, each its own protocol, so that code asks `isinstance` instead of probing with `hasattr`:
- `SeededPolicy`: `noise_seed`, combined with each episode's seed into that episode's noise stream;
- `GenerativePolicy`: samplers and a step count (`set_sampler`), as Diffusion Policy and flow matching have;
- `SelfTimedPolicy`: a policy in another process reports its own compute time (latency excludes the pipe);
- `FilmSplittable`: the exact FiLM split of the denoising U-Net that the fast inference form switches on;
- `GuidedPolicy`: samples a chunk inpainted towards the executing one (Real-Time Chunking, `--strategy rtc`);
- `CandidatePolicy`: samples n chunks per observation in one call (Bidirectional Decoding's candidates; without
  it the controller repeats the observation rows, which costs n encodings);
- `PrefixPolicy`: samples a chunk continuing a clean prefix (training-time delay conditioning, `--strategy prefix`);
- `CorrectionHead`: not a policy but a per-step residual on a policy's planned action (A2C2, `--strategy correction`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

Observation = dict[str, Any]
"""image uint8 (B, To, H, H, 3); agent_pos float32 (B, To, S); optional generators (B torch.Generator)"""


@runtime_checkable
class ChunkPolicy(Protocol):
    """The one interface bcbench needs of a policy."""

    name: str
    obs_horizon: int  # observation frames per call (To)
    pred_horizon: int  # actions per predicted chunk (Tp)
    action_horizon: int  # actions executed before re-planning (sync execution)
    chunk_start: int  # index in the chunk of the action for the current step

    def predict_action_chunk(self, obs: Observation) -> np.ndarray:
        """(B, pred_horizon, A) float32 actions in the task's units (Push-T: target positions in pixels), for a batch
        of B observation windows."""
        ...

    def describe(self) -> dict[str, Any]:
        """What result files record about the policy: at least {"name": ...}; JSON-ready."""
        ...


@runtime_checkable
class SeededPolicy(Protocol):
    """A stochastic policy whose per-episode noise streams start from `noise_seed`."""

    noise_seed: int


@runtime_checkable
class GenerativePolicy(Protocol):
    """A policy that samples its chunk in steps: a sampler kind and a step count (and a timestep spacing)."""

    samplers: tuple[str, ...]  # the sampler kinds set_sampler accepts, e.g. ("ddpm", "ddim")
    sampler_kind: str
    sampler_steps: int
    sampler_spacing: str | None

    def set_sampler(self, kind: str, steps: int, spacing: str | None = None) -> None: ...


@runtime_checkable
class FilmSplittable(Protocol):
    """A denoiser whose FiLM conditioning can be split out of the step loop (exact; the fast form)."""

    split_film: bool


@runtime_checkable
class SelfTimedPolicy(Protocol):
    """A policy whose call crosses a process boundary (a LeRobot worker): it reports the compute time of its last
    call, and latency records use that, so the pipe between the processes is not counted."""

    last_compute_s: float


@runtime_checkable
class GuidedPolicy(Protocol):
    """Real-Time Chunking's guided inpainting inside the policy's sampler (bcbench.policies.guidance)."""

    def guidance_unavailable(self, jacobian: bool = True) -> str | None:
        """None when guided sampling can run (in the current inference mode), else the reason, in one line;
        `jacobian`: through the network's Jacobian where the policy's guidance has one (False: J = I)."""
        ...

    def predict_guided_chunk(self, obs: Observation, target: np.ndarray, weights: np.ndarray,
                             max_guidance: float, jacobian: bool = True) -> np.ndarray:
        """(B, Tp, A) pixels, guided towards target (B, Tp, A) pixels with soft mask weights (B, Tp) in [0, 1]."""
        ...


@runtime_checkable
class CandidatePolicy(Protocol):
    """Several sampled chunks per observation in one call (Bidirectional Decoding)."""

    def predict_candidates(self, obs: Observation, n: int) -> np.ndarray:
        """(B, n, Tp, A) pixels; row r's candidates draw their noise in turn from row r's stream (n = 1: the chunk
        predict_action_chunk returns)."""
        ...


@runtime_checkable
class PrefixPolicy(Protocol):
    """Samples a chunk whose masked actions are given clean (training-time Real-Time Chunking, a model trained with a
    simulated delay: bcbench.policies.prefix)."""

    def prefix_unavailable(self) -> str | None:
        """None when this model can take a clean prefix (it was trained with delay conditioning), else why, in one
        line."""
        ...

    def predict_prefixed_chunk(self, obs: Observation, prefix: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(B, Tp, A) pixels continuing `prefix` (B, Tp, A) pixels where `mask` (B, Tp) is 1 (returned there as given);
        an all-zero mask samples as predict_action_chunk does."""
        ...


@runtime_checkable
class CorrectionHead(Protocol):
    """A2C2's correction head (Sendai et al. 2025, arXiv 2509.23224): every control step, a residual added to the
    action the executing chunk planned for it, from the newest observation, that action and the chunk's age."""

    def correct(self, obs: Observation, actions: np.ndarray, ages: np.ndarray, indices: np.ndarray) -> np.ndarray:
        """(B, A) pixels: `actions` (B, A) pixels corrected, given the observation windows (as a chunk request has
        them), each chunk's age `ages` (B,) (steps since its observation) and the action's index in it `indices`
        (B,)."""
        ...

    def base_mismatch(self, policy: ChunkPolicy) -> str | None:
        """None when `policy` is the base this head was trained on, else why not, in one line."""
        ...

    def describe(self) -> dict[str, Any]: ...


def example_observation(batch: int = 1, obs_horizon: int = 2, seed: int = 0, image_size: int = 96, state_dim: int = 2,
                        state_range: tuple[float, float] = (0.0, 512.0)) -> Observation:
    """A random raw observation as the controller hands it over (timing and the contract check use it); Push-T's
    shapes unless a task's are given (bcbench.evaluation.timing.task_example)."""
    rng = np.random.default_rng(seed)
    return {"image": rng.integers(0, 256, size=(batch, obs_horizon, image_size, image_size, 3), dtype=np.uint8),
            "agent_pos": rng.uniform(*state_range, size=(batch, obs_horizon, state_dim)).astype(np.float32)}


def is_generative(policy: object) -> bool:
    return isinstance(policy, GenerativePolicy) and bool(policy.samplers)


@dataclass
class RunInfo:
    """What a runner of a trained run carries besides its model: where it came from and how it is set to run.
    Written by checkpoint loading (run_dir, checkpoint, weights, preset, the sha256 of the weights and normalizer
    files), sampler configuration (sampler, steps,
    spacing) and the backends (mode, deployment); read by latency, real-time profiles and result records."""

    run_dir: str | None = None
    checkpoint: str | None = None
    weights: str | None = None  # "ema" or "raw"
    preset: str | None = None
    sampler: str | None = None
    steps: int | None = None
    spacing: str | None = None
    mode: str | None = None  # bcbench.modes.MODES; None: never switched (the fast form)
    deployment: dict[str, Any] | None = None
    weights_sha256: str | None = None  # of the weights file loaded: which model a record ran, whatever its folder
    normalizer_sha256: str | None = None  # of its normalizer.json (the same weights with other statistics differ)

    def describe(self) -> dict[str, Any]:
        """The fields that are set, for result files (the keys records have always used)."""
        return {k: v for k, v in asdict(self).items() if v is not None or (k == "preset" and self.run_dir)}
