"""Image Push-T (Diffusion Policy's, Chi et al., RSS 2023): the study's task.

Two 96x96 RGB frames and the agent's position in; target agent positions in pixels of the 512 px world out,
at 10 Hz; an episode's score is its maximum reward min(coverage / 0.95, 1), at most 300 steps, ending early at
coverage > 0.95; test seeds 100000-100099 start from Diffusion Policy's seeded states.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.tasks.spec import Episode, Obs, Task

WORLD = 512.0


class PushTEpisode:
    """One Push-T environment at a seed's start state (gym-pusht, reset exactly: `env.PushTEnv`)."""

    def __init__(self, seed: int, video_size: int | None = None) -> None:
        from bcbench.tasks.pusht.env import dp_initial_state, make_env  # pymunk/pygame only in the simulator

        self.seed = seed
        self.env = make_env(video_size=video_size)
        self._start = dp_initial_state(seed)

    def reset(self) -> tuple[Obs, float, list[float]]:
        obs, _ = self.env.reset(options={"reset_to_state": self._start})
        return obs, self.env.coverage(), self._start.tolist()

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, float, list[float]]:
        obs, reward, terminated, _, info = self.env.step(np.asarray(action, dtype=np.float64))
        state = [*map(float, info["pos_agent"]), *map(float, info["block_pose"])]
        return obs, float(reward), bool(terminated), float(info["coverage"]), state

    def render(self) -> np.ndarray:
        return self.env.render()

    def close(self) -> None:
        self.env.close()


def _episode(seed: int, video_size: int | None) -> Episode:
    return PushTEpisode(seed, video_size)


def _dataset(path: str | None) -> Path:
    from bcbench.data.paths import resolve_dataset

    return resolve_dataset(path)


def _load(path: Path, images: bool) -> ReplayBuffer:
    from bcbench.data.replay_buffer import load_replay_buffer

    return load_replay_buffer(path, images=images)


TASK = Task(
    name="pusht", family="pusht", image_size=96, camera="top-down (gym-pusht's render)",
    state_names=("agent_x", "agent_y"), action_names=("target_x", "target_y"),
    action_low=(0.0, 0.0), action_high=(WORLD, WORLD), state_range=(0.0, WORLD),
    action_units="target agent position in pixels of the 512 px world (a PD controller follows it)",
    control_hz=10.0, max_steps=300,
    score="maximum reward over the episode, reward = min(coverage / 0.95, 1)",
    success="coverage of the goal T above 0.95 (the episode ends)",
    progress="coverage: the share of the goal T's area the block covers",
    make_episode=_episode, dataset=_dataset, load_buffer=_load,
    notes="Diffusion Policy's seeded reset (legacy RandomState draw, block angle set before its position)",
    instruction="Push the T-shaped block onto the T-shaped target.",
)
