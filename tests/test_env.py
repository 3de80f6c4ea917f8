"""The simulator reproduces the recorded scenes; seeded starts follow Diffusion Policy."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from bcbench.data import load_replay_buffer
from bcbench.tasks.pusht.env import dp_initial_state, goal_centroid, make_env, reward_from_coverage
from bcbench.tasks.pusht.replay import replay_buffer_episodes, replay_episode, replay_report

EPISODES = [0, 41, 102, 163, 205]


@pytest.fixture(scope="module")
def real_buffer(real_zarr):
    return load_replay_buffer(real_zarr, images=False)


def test_replay_is_exact_on_several_episodes(real_buffer):
    results = replay_buffer_episodes(real_buffer, EPISODES, workers=1, progress=False)
    assert [r.episode for r in results] == EPISODES
    for r in results:
        assert r.max_block_error_px <= 1.0, (r.episode, r.max_block_error_px)
        assert r.max_angle_error_rad <= 0.01
        assert 0.0 <= r.score <= 1.0
    report = replay_report(results)
    assert report["exact_fraction"] == 1.0
    assert report["demonstrators"]["mean_score"]["value"] > 0.8  # humans nearly finish every demo


def test_upstream_reset_order_would_be_wrong(real_buffer):
    """Guard for the fix: gym-pusht's own reset (position before angle) puts the block elsewhere."""
    from gym_pusht.envs.pusht import PushTEnv as Upstream

    state = real_buffer.state[real_buffer.episode_slice(0)][0]
    upstream = Upstream(obs_type="state")
    obs_up, _ = upstream.reset(options={"reset_to_state": state})
    obs_ok, _ = make_env(obs_type="state").reset(options={"reset_to_state": state})
    assert np.abs(obs_ok[2:4] - state[2:4]).max() < 1e-3
    assert np.abs(obs_up[2:4] - state[2:4]).max() > 5.0


def test_replay_worker_matches_record_step_by_step(real_buffer):
    sl = real_buffer.episode_slice(3)
    r = replay_episode((3, real_buffer.state[sl], real_buffer.action[sl]))
    assert r.length == sl.stop - sl.start and r.max_block_error_px < 1.0


def test_rendered_observation_matches_recorded_image(real_zarr):
    root = zarr.open_group(str(real_zarr), mode="r")
    state, img = root["data/state"][0], root["data/img"][0]
    obs, _ = make_env().reset(options={"reset_to_state": state})
    assert obs["pixels"].shape == (96, 96, 3) and obs["pixels"].dtype == np.uint8
    assert np.abs(obs["pixels"].astype(np.float32) - img).mean() < 1.0  # same scene, same renderer


def test_dp_initial_state_is_seeded_and_in_range():
    a, b = dp_initial_state(100000), dp_initial_state(100000)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, dp_initial_state(100001))
    states = np.stack([dp_initial_state(100000 + i) for i in range(50)])
    assert states[:, :2].min() >= 50 and states[:, :2].max() < 450
    assert states[:, 2:4].min() >= 100 and states[:, 2:4].max() < 400


def test_goal_and_reward():
    env = make_env(obs_type="state")
    env.reset(options={"reset_to_state": [100, 100, 256, 256, np.pi / 4]})  # block exactly on the goal
    assert env.coverage() > 0.99
    assert reward_from_coverage(0.95) == 1.0 and reward_from_coverage(0.475) == pytest.approx(0.5)
    assert np.linalg.norm(goal_centroid() - np.array([256, 256])) == pytest.approx(40.71, abs=0.05)


def test_the_fast_frame_is_upstreams_frame_pixel_for_pixel():
    """PushTEnv._get_img reads the surface's RGB bytes instead of upstream's copy-and-transpose: the same pixels at
    the observation's, a video's and the world's size, on moving scenes; a frame with the action drawn is upstream's."""
    from gym_pusht.envs.pusht import PushTEnv as Upstream

    env = make_env(video_size=256)
    env.reset(options={"reset_to_state": dp_initial_state(100000)})
    rng = np.random.default_rng(0)
    compared = 0
    for step in range(30):
        env.step(rng.uniform(50.0, 460.0, size=2))
        screen = env._draw()
        for size in (96, 256, 512):
            ours, theirs = env._get_img(screen, size, size), Upstream._get_img(env, screen, size, size)
            assert ours.dtype == theirs.dtype and np.array_equal(ours, theirs), (step, size)
            compared += 1
        drawn = env._get_img(screen, 256, 256, render_action=True)  # the marker: upstream's path
        assert np.array_equal(drawn, Upstream._get_img(env, screen, 256, 256, render_action=True))
    assert compared == 90 and not np.array_equal(drawn, env._get_img(screen, 256, 256))  # the marker was drawn
