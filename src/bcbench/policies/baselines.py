"""Two non-learned baselines that exercise the harness and bracket what a cloned policy should beat.

- `random`: every action uniform within the task's action bounds (Push-T: a target position over the 512x512
  world), on any task: the chance level finding 5 compares BeT with.
- `scripted`: a vision-only heuristic. It finds the T in the 96x96 image by colour, walks around it to
  the side opposite the goal, then pushes it in a straight line towards the goal (translation only: it
  never tries to turn the T, so it rarely reaches the 95% coverage that counts as success).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from bcbench.errors import BCBenchError
from bcbench.tasks import Task, get_task
from bcbench.tasks.pusht.env import WORLD_SIZE, goal_centroid

_BLOCK_RGB = np.array([119, 136, 153], dtype=np.float32)  # pygame's LightSlateGray, the T's colour


@dataclass
class BaselineConfig:
    """Shared by both baselines: they have no weights, so `quick` and `paper` are the same."""

    seed: int = 0
    """seed of the policy's own random generator"""
    obs_horizon: int = 2
    """observations per call (the study's 2 frames)"""
    pred_horizon: int = 16
    """actions per chunk"""
    action_horizon: int = 8
    """actions executed before re-planning"""
    step_px: float = 12.0
    """scripted only: distance the target moves per action, in world pixels"""
    standoff_px: float = 85.0
    """scripted only: distance behind the T's centroid where a push starts"""

    def __post_init__(self) -> None:
        if not 1 <= self.action_horizon <= self.pred_horizon:
            raise BCBenchError(f"need 1 <= action_horizon <= pred_horizon, got {self.action_horizon}")
        if self.obs_horizon < 1:
            raise BCBenchError(f"obs_horizon must be >= 1, got {self.obs_horizon}")
        if self.step_px <= 0 or self.standoff_px <= 0:
            raise BCBenchError("step_px and standoff_px must be positive")

    @classmethod
    def preset(cls, name: str) -> BaselineConfig:
        if name not in ("quick", "paper"):
            raise BCBenchError(f"unknown preset '{name}' (choose quick or paper; a baseline has no sizes)")
        return cls()


def task_refusal(name: str, only_task: str | None, task: str) -> str | None:
    """Why baseline `name` (acting in `only_task` alone, or anywhere if None) cannot act in `task`; None if it can.
    One text for make_policy's refusal and a study's, which refuses before hours of training."""
    if only_task in (None, task):
        return None
    where = "Push-T" if only_task == "pusht" else only_task
    return f"the {name} baseline acts in {where}'s world; it has no version for {task} (random acts on every task)"


class _Baseline:
    name = "baseline"
    chunk_start = 0
    only_task: str | None = None  # the one task it can act in (None: any); a study or make_policy refuses others

    def __init__(self, config: BaselineConfig, task: Task | None = None) -> None:
        task = task or get_task()
        if why := task_refusal(self.name, self.only_task, task.name):
            raise BCBenchError(why)
        self.task = task.name  # evaluation refuses episodes of any other task
        self.config = config
        self.obs_horizon = config.obs_horizon
        self.pred_horizon = config.pred_horizon
        self.action_horizon = config.action_horizon
        self.rng = np.random.default_rng(config.seed)

    @property
    def noise_seed(self) -> int:
        return self.config.seed

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "parameters": 0, "config": asdict(self.config),
                **({"task": self.task} if self.task != "pusht" else {})}  # Push-T's records stay as they were


class RandomPolicy(_Baseline):
    name = "random"

    def __init__(self, config: BaselineConfig, task: Task | None = None) -> None:
        super().__init__(config, task)
        bounds = task or get_task()
        self._low = np.asarray(bounds.action_low, dtype=np.float64)  # (A,)
        self._span = np.asarray(bounds.action_high, dtype=np.float64) - self._low
        # Push-T's [0, 512]: 0 + u * 512 is bit for bit the u * 512 its committed scores were drawn with (tested)

    def predict_action_chunk(self, obs: dict[str, Any]) -> np.ndarray:
        gens = obs.get("generators")  # per-episode streams from the controller: rows independent of batching
        shape = (1, self.pred_horizon, len(self._span))
        if gens is None:
            u = self.rng.uniform(size=(obs["agent_pos"].shape[0], *shape[1:]))
        else:
            u = torch.cat([torch.rand(shape, generator=g, dtype=torch.float64) for g in gens]).numpy()
        return (self._low + u * self._span).astype(np.float32)  # (B, Tp, A)


def block_centroid(image: np.ndarray) -> np.ndarray | None:
    """World position of the T's visible centroid in a 96x96 RGB frame, or None if not visible."""
    dist = np.linalg.norm(image.astype(np.float32) - _BLOCK_RGB, axis=-1)  # (H, W)
    rows, cols = np.nonzero(dist < 30.0)
    if rows.size < 5:
        return None
    scale = WORLD_SIZE / image.shape[0]
    return np.array([(cols.mean() + 0.5) * scale, (rows.mean() + 0.5) * scale])


class ScriptedPolicy(_Baseline):
    name = "scripted"
    only_task = "pusht"  # it finds Push-T's T by colour and walks in its 512 px world

    def __init__(self, config: BaselineConfig, task: Task | None = None) -> None:
        super().__init__(config, task)
        self.goal = goal_centroid()

    def _path(self, start: np.ndarray, waypoints: list[np.ndarray]) -> np.ndarray:
        """pred_horizon targets that walk from start through the waypoints at step_px per action."""
        out, pos = [], start.copy()
        queue = list(waypoints)
        while len(out) < self.pred_horizon:
            if not queue:
                out.append(pos.copy())
                continue
            delta = queue[0] - pos
            dist = float(np.linalg.norm(delta))
            pos = queue.pop(0).copy() if dist <= self.config.step_px else pos + delta / dist * self.config.step_px
            out.append(pos.copy())
        return np.clip(np.stack(out), 0.0, WORLD_SIZE)

    def _plan_one(self, image: np.ndarray, agent: np.ndarray) -> np.ndarray:
        block = block_centroid(image)
        if block is None:
            return self._path(agent, [])
        to_goal = self.goal - block
        dist = float(np.linalg.norm(to_goal))
        if dist < 4.0:  # close enough: stay out of the way
            return self._path(agent, [])
        d = to_goal / dist
        normal = np.array([-d[1], d[0]])
        rel = agent - block
        along, across = float(rel @ d), float(rel @ normal)
        push_start = block - d * self.config.standoff_px
        if along < -0.6 * self.config.standoff_px and abs(across) < 20.0:
            # Behind the T and lined up: push straight through it towards the goal.
            return self._path(agent, [block + d * dist])
        # Otherwise go around the T on the side the agent is already on, then line up behind it.
        side = 1.0 if across >= 0 else -1.0
        around = block + normal * side * (self.config.standoff_px + 30.0) - d * 0.5 * self.config.standoff_px
        waypoints = [push_start] if along < -0.3 * self.config.standoff_px else [around, push_start]
        return self._path(agent, waypoints)

    def predict_action_chunk(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        image, agent_pos = obs["image"][:, -1], obs["agent_pos"][:, -1]  # newest frame: (B, H, W, 3), (B, A)
        return np.stack([self._plan_one(im, ag) for im, ag in zip(image, agent_pos, strict=True)]).astype(np.float32)
