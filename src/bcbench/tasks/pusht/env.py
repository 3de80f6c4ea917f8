"""The Push-T simulator (gym-pusht), reset exactly and seeded as in Diffusion Policy (Chi et al., 2023).

gym-pusht's `reset_to_state` sets the block's position before its angle. pymunk turns a body about its
centre of gravity, which for the T sits 45 px from the body origin, so setting the angle second moves the
block away from the recorded pose (by up to 90 px). The demonstrations were recorded with the angle set
first (Diffusion Policy's `legacy=False`), so that is what `PushTEnv._set_state` does. This module is the
one place that knows it.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

from bcbench.utils.system import require_known_version

require_known_version("gym-pusht")  # the exact reset below overrides one of its internals

with warnings.catch_warnings():
    # pygame (imported by gym-pusht) reaches for setuptools' pkg_resources where it is installed, which then warns
    # on every command that it is deprecated; pygame falls back without it, and bcbench uses none of it
    warnings.filterwarnings("ignore", message="pkg_resources is deprecated", category=UserWarning)
    import cv2
    import pygame
    from gym_pusht.envs.pusht import PushTEnv as _GymPushTEnv

WORLD_SIZE = 512.0
MAX_STEPS = 300  # Diffusion Policy's episode limit
SUCCESS_COVERAGE = 0.95
GOAL_POSE = np.array([256.0, 256.0, np.pi / 4])  # x, y, angle of the target T
# The T's area centroid in its body frame: bar 120x30 centred at y=15, stem 30x90 centred at y=75.
T_CENTROID_LOCAL = np.array([0.0, (3600 * 15 + 2700 * 75) / 6300])


class PushTEnv(_GymPushTEnv):
    """gym-pusht with the exact reset: block angle first, then position, as the recorded states assume."""

    def _set_state(self, state):  # type: ignore[override]
        state = np.asarray(state, dtype=np.float64).tolist()
        self.agent.position = state[:2]
        self.block.angle = state[4]  # turn about the centre of gravity first ...
        self.block.position = state[2:4]  # ... then place the body origin where the record says
        self.space.step(self.dt)  # as upstream: one physics step makes the pose take effect

    def coverage(self) -> float:
        return float(self._get_coverage())

    def _get_img(self, screen, width, height, render_action=False):  # type: ignore[override]
        """Upstream's frame, pixel for pixel, without its slowest line: it copies pygame's column-major pixel view
        into a new array and transposes it (about 2.5 ms of a 4 ms step here); the surface's row-major RGB bytes are
        that image already. A frame that draws the last action (a video's) goes upstream's way."""
        if render_action:
            return super()._get_img(screen, width, height, render_action)
        rows = np.frombuffer(pygame.image.tobytes(screen, "RGB"), dtype=np.uint8)
        return cv2.resize(rows.reshape(screen.get_height(), screen.get_width(), 3), (width, height))


def dp_initial_state(seed: int) -> np.ndarray:
    """Diffusion Policy's seeded start state (legacy RandomState draw), so seed s is the literature's seed s."""
    rs = np.random.RandomState(seed=seed)
    return np.array(
        [
            rs.randint(50, 450),
            rs.randint(50, 450),
            rs.randint(100, 400),
            rs.randint(100, 400),
            rs.randn() * 2 * np.pi - np.pi,
        ],
        dtype=np.float64,
    )


def make_env(obs_type: str = "pixels_agent_pos", video_size: int | None = None) -> PushTEnv:
    """A Push-T env with 96x96 observations; `video_size` sets the resolution of `env.render()` frames."""
    size = video_size or 256
    return PushTEnv(obs_type=obs_type, render_mode="rgb_array", visualization_width=size, visualization_height=size)


def goal_centroid() -> np.ndarray:
    """World position of the goal T's area centroid."""
    c, s = np.cos(GOAL_POSE[2]), np.sin(GOAL_POSE[2])
    x, y = T_CENTROID_LOCAL
    return GOAL_POSE[:2] + np.array([c * x - s * y, s * x + c * y])


def reward_from_coverage(coverage: float) -> float:
    """Diffusion Policy's reward: coverage / 0.95 clipped to [0, 1]."""
    return float(np.clip(coverage / SUCCESS_COVERAGE, 0.0, 1.0))
