"""Open-loop replay of the recorded demonstrations: is the simulator the one the data came from?

Each episode starts from its recorded first state and executes its recorded actions. We report the
largest block-position error against the recorded states over the whole episode, and the demonstrator's
score (max reward over the episode), which is the ceiling a cloned policy can hope for.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.stats import score_summary
from bcbench.tasks.pusht.env import SUCCESS_COVERAGE, make_env

EXACT_PX = 1.0  # an episode is "exact" when the block never strays more than this from the record


@dataclass
class EpisodeReplay:
    episode: int
    length: int
    max_block_error_px: float
    max_angle_error_rad: float
    score: float
    final_coverage: float
    success: bool

    @property
    def exact(self) -> bool:
        return self.max_block_error_px <= EXACT_PX


def _angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + np.pi) % (2 * np.pi) - np.pi)


def replay_episode(args: tuple[int, np.ndarray, np.ndarray]) -> EpisodeReplay:
    """Replay one episode given (index, states (L,5), actions (L,2))."""
    episode, states, actions = args
    env = make_env(obs_type="state")
    obs, _ = env.reset(options={"reset_to_state": states[0]})
    pos_err = [float(np.abs(obs[2:4] - states[0, 2:4]).max())]
    ang_err = [float(_angle_diff(obs[4], states[0, 4]))]
    rewards, coverage = [], env.coverage()
    max_coverage = coverage
    # Action t moves the scene from state t to state t+1; the last action has no recorded successor,
    # but it still counts for the demonstrator's score.
    for t in range(len(actions)):
        obs, reward, _terminated, _, info = env.step(actions[t])
        rewards.append(float(reward))
        coverage = float(info["coverage"])
        max_coverage = max(max_coverage, coverage)
        if t + 1 < len(states):
            pos_err.append(float(np.abs(obs[2:4] - states[t + 1, 2:4]).max()))
            ang_err.append(float(_angle_diff(obs[4], states[t + 1, 4])))
    env.close()
    return EpisodeReplay(
        episode=episode, length=len(states), max_block_error_px=max(pos_err), max_angle_error_rad=max(ang_err),
        score=max(rewards) if rewards else 0.0, final_coverage=coverage,
        success=bool(max_coverage > SUCCESS_COVERAGE),
    )


def replay_buffer_episodes(
    buf: ReplayBuffer, episodes: list[int] | None = None, workers: int | None = None, progress: bool = True
) -> list[EpisodeReplay]:
    """Replay the given episodes (default: all) in parallel worker processes."""
    episodes = list(range(buf.n_episodes)) if episodes is None else list(episodes)
    jobs = [(e, buf.state[buf.episode_slice(e)], buf.action[buf.episode_slice(e)]) for e in episodes]
    workers = max(1, min(workers or os.cpu_count() or 1, len(jobs)))
    bar = tqdm(total=len(jobs), desc="replay", unit="ep", disable=not progress)
    out: list[EpisodeReplay] = []
    if workers == 1:
        for job in jobs:
            out.append(replay_episode(job))
            bar.update()
    else:
        with mp.get_context("spawn").Pool(workers) as pool:
            for res in pool.imap(replay_episode, jobs, chunksize=4):
                out.append(res)
                bar.update()
    bar.close()
    return out


def replay_report(results: list[EpisodeReplay]) -> dict[str, Any]:
    """Exactness and demonstrator-score summary of a replay."""
    errs = np.array([r.max_block_error_px for r in results])
    exact = np.array([r.exact for r in results])
    return {
        "episodes": len(results),
        "exact_episodes": int(exact.sum()),
        "exact_fraction": float(exact.mean()) if len(results) else 0.0,
        "exact_threshold_px": EXACT_PX,
        "block_error_px": {
            "median": float(np.median(errs)), "p95": float(np.percentile(errs, 95)), "max": float(errs.max())
        },
        "demonstrators": score_summary(
            np.array([r.score for r in results]), np.array([r.success for r in results]),
            np.array([r.final_coverage for r in results]),
        ),
        "per_episode": [asdict(r) for r in results],
    }
