"""What a task is to bcbench: the one place that knows a task's shapes, units, reset, score and seeds.

Everything below the task (data) is task-agnostic storage; everything above it (policies, controller, evaluation,
latency, real time, studies, reports) reads the task's `Task` and hard-codes no shape. A new task family is one
package under `bcbench.tasks` that returns `Task`s (as LeRobot's `envs/configs.py` or Diffusion Policy's
`config/task/` do).

An episode (`Episode`) is one seeded environment: `reset()` puts it in the seed's start state, `step(action)`
advances one control step. Observations are {"pixels": uint8 (H, W, 3), "agent_pos": float (S,)}: the camera
frame and the task's proprioceptive state (the name is Push-T's, kept so that every model, normaliser and record
written before tasks existed still reads; for another task it is the task's `state_names`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.errors import BCBenchError
from bcbench.interface import example_observation
from bcbench.protocol import CONTROL_DT_S, TEST_SEED_START, VALIDATION_SEED_START

Obs = dict[str, np.ndarray]


class Episode(Protocol):
    """One seeded environment, driven one control step at a time (in a simulator worker process)."""

    def reset(self) -> tuple[Obs, float, list[float]]:
        """The seed's start: (observation, progress, state) where state is what records keep of the world."""
        ...

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, float, list[float]]:
        """(observation, reward in [0, 1], terminated (success: the episode ends), progress, state)."""
        ...

    def render(self) -> np.ndarray:
        """A uint8 (V, V, 3) frame for the rollout video."""
        ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Task:
    """A task: observation and action specs, control rate, episode rules, seeds and demonstrations."""

    name: str
    """`pusht`, `metaworld/drawer-open`, ...: what `--task` takes and run.json records"""
    image_size: int
    """side of the square camera frame a policy reads"""
    camera: str
    """which camera the frame comes from"""
    state_names: tuple[str, ...]
    """the proprioceptive observation `agent_pos`, one name a dimension"""
    action_names: tuple[str, ...]
    """one name an action dimension"""
    action_low: tuple[float, ...]
    """lower bound of each action dimension, in the task's units"""
    action_high: tuple[float, ...]
    """upper bound of each action dimension"""
    action_units: str
    """what an action is, in words (Push-T: target agent position in pixels of the 512 px world)"""
    control_hz: float
    """control steps a second (the real-time delay d = ceil(latency x rate))"""
    max_steps: int
    """episode length cap in control steps"""
    score: str
    """the per-episode score, in words"""
    success: str
    """what ends an episode early, in words"""
    progress: str
    """the progress measure kept per episode (`final_coverage` / `max_coverage` in records), in words"""
    make_episode: Callable[[int, int | None], Episode] = field(repr=False, compare=False)
    """(seed, video frame size or None) -> a fresh episode in the seed's start state after reset()"""
    dataset: Callable[[str | None], Path] = field(repr=False, compare=False)
    """the demonstrations' replay buffer: an explicit path (checked) or None (the task's default place)"""
    load_buffer: Callable[[Path, bool], ReplayBuffer] = field(repr=False, compare=False)
    """(path, with images) -> the demonstrations, checked against this task's shapes"""
    test_seed_start: int = TEST_SEED_START
    """test episodes use seeds test_seed_start + i"""
    validation_seed_start: int = VALIDATION_SEED_START
    """validation episodes use seeds validation_seed_start + i"""
    step_limit: int | None = None
    """the most steps the simulator allows in an episode (MetaWorld raises past 500), None: no limit"""
    action_hold: tuple[bool, ...] | None = None
    """what the robot does while no action is queued (waiting for a chunk): per action dimension, True = the last
    command is kept (a gripper's), False = zeroed (a displacement); None = every dimension kept, the actions being
    absolute targets that equal the proprioception at rest (Push-T's positions)"""
    state_range: tuple[float, float] = (-1.0, 1.0)
    """where proprioception values lie, roughly: timing's random observations are drawn in it"""
    family: str = ""
    """pusht, metaworld, ..."""
    difficulty: str | None = None
    """a published difficulty group, where the family has one (MetaWorld: Seo et al.'s easy/medium/hard/very hard)"""
    notes: str = ""
    """anything else a reader needs (camera choice, proprioception, why a cap)"""
    instruction: str = ""
    """the task in one sentence, as language-conditioned datasets state it (LeRobot's task string); empty: the
    LeRobot export makes one from the name"""

    def __post_init__(self) -> None:
        if not self.name:
            raise BCBenchError("a task needs a name")
        if self.image_size < 8 or self.max_steps < 1 or not self.control_hz > 0:
            raise BCBenchError(f"task {self.name}: need image_size >= 8, max_steps >= 1 and control_hz > 0")
        if not self.state_names or not self.action_names:
            raise BCBenchError(f"task {self.name}: needs state_names and action_names")
        if not len(self.action_low) == len(self.action_high) == len(self.action_names):
            raise BCBenchError(f"task {self.name}: action_low, action_high and action_names differ in length")
        if any(lo >= hi for lo, hi in zip(self.action_low, self.action_high, strict=True)):
            raise BCBenchError(f"task {self.name}: every action_low must be below its action_high")
        if self.step_limit is not None and self.max_steps > self.step_limit:
            raise BCBenchError(f"task {self.name}: cap {self.max_steps} above the simulator's limit {self.step_limit}")
        if self.action_hold is not None and len(self.action_hold) != len(self.action_names):
            raise BCBenchError(f"task {self.name}: action_hold needs one entry per action dimension")

    @property
    def state_dim(self) -> int:
        return len(self.state_names)

    @property
    def action_dim(self) -> int:
        return len(self.action_names)

    @property
    def delay_rate(self) -> float | None:
        """The rate a latency becomes a delay in steps at (protocol.delay_steps): None for the protocol's own 10 Hz
        (Push-T: its one rounding, ceil(L / 0.1 s)), else this task's control rate."""
        return None if self.control_hz * CONTROL_DT_S == 1.0 else self.control_hz

    @property
    def step_s(self) -> float:
        """Seconds of the world a control step takes."""
        return CONTROL_DT_S if self.delay_rate is None else 1.0 / self.control_hz

    def hold_action(self, obs: Obs) -> np.ndarray:
        """The action (A,) that keeps the robot where it is before any chunk arrived: an absolute-target task's
        current position (Push-T), a displacement task's zero (MetaWorld's gripper is a position actuator, 0 keeps
        it open, as every episode starts)."""
        if self.action_hold is None:
            return np.asarray(obs["agent_pos"], dtype=np.float32)
        return np.zeros(self.action_dim, dtype=np.float32)

    def waiting_action(self, last: np.ndarray) -> np.ndarray:
        """The action (A,) of a step with no action queued, after `last` (A,): `last` itself for absolute targets
        (Push-T's target held), else `last` with its displacements zeroed (stand still, keep the grip)."""
        if self.action_hold is None:
            return last
        return np.where(np.asarray(self.action_hold), last, 0.0).astype(np.float32)

    def example_observation(self, batch: int = 1, obs_horizon: int = 2, seed: int = 0) -> Obs:
        """A random raw observation window of this task's shapes (B, To, ...), as timing calls a policy with."""
        return example_observation(batch, obs_horizon, seed, self.image_size, self.state_dim, self.state_range)

    def demonstrations(self, path: str | None = None, images: bool = True) -> ReplayBuffer:
        """The task's demonstrations (from `path`, else the default place), shapes checked against the task's."""
        buf = self.load_buffer(self.dataset(path), images)
        if buf.state.shape[1] < self.state_dim or buf.action.shape[1] != self.action_dim:
            raise BCBenchError(f"{buf.source}: state {buf.state.shape[1:]} / action {buf.action.shape[1:]} do not fit "
                               f"task {self.name} ({self.state_dim} state values, {self.action_dim} action values)")
        if buf.images is not None and buf.images.shape[1:] != (self.image_size, self.image_size, 3):
            raise BCBenchError(f"{buf.source}: frames {buf.images.shape[1:]}, task {self.name} reads "
                               f"{self.image_size}x{self.image_size}x3")
        return buf

    def describe(self) -> dict[str, Any]:
        """JSON-ready: what records keep of the task (no callables)."""
        return {"name": self.name, "family": self.family, "image_size": self.image_size, "camera": self.camera,
                "state_names": list(self.state_names), "action_names": list(self.action_names),
                "action_low": list(self.action_low), "action_high": list(self.action_high),
                "action_units": self.action_units, "control_hz": self.control_hz, "max_steps": self.max_steps,
                "score": self.score, "success": self.success, "progress": self.progress,
                "test_seed_start": self.test_seed_start, "validation_seed_start": self.validation_seed_start,
                "step_limit": self.step_limit, "action_hold": None if self.action_hold is None else
                list(self.action_hold), "state_range": list(self.state_range),
                "difficulty": self.difficulty, "notes": self.notes}
