"""MetaWorld tasks: seeded resets, the fast camera, the scripted expert through the Episode wrapper, and the
demonstration generator and its store (about a minute on 2 cores)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
pytest.importorskip("metaworld", reason="MetaWorld is not installed (pip install -e .[metaworld])")

from bcbench.errors import BCBenchError, DatasetError
from bcbench.tasks import get_task, task_names
from bcbench.tasks.metaworld import load_metaworld_buffer, metaworld_task
from bcbench.tasks.metaworld.env import FLIPPED_CAMERAS, MetaWorldEpisode
from bcbench.tasks.metaworld.generate import generate
from bcbench.tasks.metaworld.reader import store_info
from bcbench.tasks.metaworld.table import TASKS

pytestmark = pytest.mark.filterwarnings("ignore:Constant.s. may be too high")  # the experts' gains

NAMES = list(TASKS)
SRC = str(Path(__file__).resolve().parents[1] / "src")


def _expert(name: str):
    import metaworld.policies as policies

    return getattr(policies, TASKS[name]["expert"])()


# ------------------------------------------------------------------ the Task
def test_unknown_name_is_one_clear_error():
    with pytest.raises(BCBenchError, match="drawer-open, door-open"):
        get_task("metaworld/no-such-task")
    with pytest.raises(BCBenchError, match="unknown MetaWorld task"):
        MetaWorldEpisode("no-such-task", 0)
    assert all(f"metaworld/{n}" in task_names() for n in NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_task_describes_itself(name):
    task = get_task(f"metaworld/{name}")
    assert task.family == "metaworld" and task.name == f"metaworld/{name}"
    assert task.state_dim == len(TASKS[name]["proprio"]) and task.action_dim == 4
    assert task.control_hz == 80.0 and task.max_steps <= 500
    assert task.max_steps >= 1.5 * TASKS[name]["expert_length"][1]
    assert ("goal_x" in task.state_names) == (name in ("pick-place", "stick-pull"))
    json.dumps(task.describe())


def test_a_larger_frame_is_its_own_task_and_only_the_frame_changes():
    """metaworld/pick-place@128: the same world, proprioception, actions and rules, 128 px frames; its own name (so
    its own run keys and store); the family's 96 takes no suffix and an unknown size is refused."""
    big, small = get_task("metaworld/pick-place@128"), get_task("metaworld/pick-place")
    assert (big.name, big.image_size, small.image_size) == ("metaworld/pick-place@128", 128, 96)
    same = ("state_names", "action_names", "action_low", "action_high", "control_hz", "max_steps", "difficulty",
            "camera", "step_limit", "action_hold")
    assert all(getattr(big, k) == getattr(small, k) for k in same)
    assert "frames at 128 px" in big.notes and "frames at" not in small.notes
    for bad, msg in (("pick-place@96", "takes no suffix"), ("pick-place@100", "is one of 128"),
                     ("nope@128", "unknown MetaWorld task 'nope'")):
        with pytest.raises(BCBenchError, match=msg):
            get_task(f"metaworld/{bad}")
    a, b = big.make_episode(7, None), small.make_episode(7, None)
    try:
        (oa, _, _), (ob, _, _) = a.reset(), b.reset()
        assert oa["pixels"].shape == (128, 128, 3) and ob["pixels"].shape == (96, 96, 3)
        assert np.array_equal(oa["agent_pos"], ob["agent_pos"])
    finally:
        a.close()
        b.close()


# ------------------------------------------------------------------ the episode
@pytest.mark.parametrize("name", NAMES)
def test_expert_succeeds_through_the_episode(name):
    """Seed 1 is a success for every task's expert (table.py's measurement); shapes match the Task."""
    task = metaworld_task(name)
    ep = task.make_episode(1, 64)
    try:
        obs, progress, state = ep.reset()
        assert obs["pixels"].shape == (task.image_size, task.image_size, 3) and obs["pixels"].dtype == np.uint8
        assert obs["agent_pos"].shape == (task.state_dim,) and obs["agent_pos"].dtype == np.float32
        assert 0.0 <= progress <= 1.0 and len(state) == 9
        assert ep.render().shape == (64, 64, 3)
        expert = _expert(name)
        for _ in range(task.max_steps):
            obs, reward, terminated, progress, state = ep.step(expert.get_action(ep.full_obs))
            assert 0.0 <= progress <= 1.0
            if terminated:
                break
        assert terminated and reward == 1.0
        assert obs["agent_pos"].shape == (task.state_dim,) and len(state) == 9
    finally:
        ep.close()


_PROBE = """
import os, sys, numpy as np
os.environ.setdefault("MUJOCO_GL", "egl")
from bcbench.tasks.metaworld.env import MetaWorldEpisode
ep = MetaWorldEpisode("pick-place", int(sys.argv[1]))
obs, _, state = ep.reset()
frames, states = [obs["pixels"]], [state]
for _ in range(3):
    obs, *_, state = ep.step(np.array([0.5, -0.3, 0.2, 1.0]))
    frames.append(obs["pixels"]); states.append(state)
np.savez(sys.argv[2], frames=np.stack(frames), states=np.array(states), agent_pos=obs["agent_pos"])
ep.close()
"""


def _probe(seed: int, out: Path) -> dict[str, np.ndarray]:
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    subprocess.run([sys.executable, "-c", _PROBE, str(seed), str(out)], check=True, env=env, timeout=120)
    return dict(np.load(out))


def test_seeded_reset_is_the_same_in_two_processes_and_differs_across_seeds(tmp_path):
    a = _probe(7, tmp_path / "a.npz")
    b = _probe(7, tmp_path / "b.npz")
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    ep = MetaWorldEpisode("pick-place", 8)  # a third process (this one), another seed
    try:
        obs, _, state = ep.reset()
        assert not np.allclose(state[3:], a["states"][0][3:])  # object and goal moved
        assert not np.array_equal(obs["pixels"], a["frames"][0])
        obs, _, state = ep.reset(seed=7)  # and back: the same start as the other processes
        assert state == a["states"][0].tolist() and np.array_equal(obs["pixels"], a["frames"][0])
        # the frame shows this seed's goal marker, not the one MetaWorld's reset drew before (it moves the site
        # after its last mj_forward)
        assert np.allclose(ep.env.data.site("goal").xpos, ep.full_obs[36:39])
    finally:
        ep.close()


def _default_render_env(name: str, seed: int):
    """MetaWorld's own rendering (gymnasium's renderer, multisampling and shadows on), same seeding as ours."""
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS

    env = ALL_V3_ENVIRONMENTS[TASKS[name]["env"]](render_mode="rgb_array", camera_name=TASKS[name]["camera"],
                                                  width=96, height=96)
    env._partially_observable = False
    env.__dict__.pop("sawyer_observation_space", None)
    env._freeze_rand_vec, env.seeded_rand_vec, env._set_task_called = False, True, True
    env.seed(seed)
    env.reset()
    return env


def _default_frame(env, camera: str) -> np.ndarray:
    viewer = env.mujoco_renderer._get_viewer("rgb_array")
    viewer.make_context_current()  # gymnasium draws in whatever context is current (ours, otherwise)
    img = env.render()
    return img[::-1, ::-1] if camera in FLIPPED_CAMERAS else img


def _close_default(env) -> None:
    viewer = env.mujoco_renderer._viewers.get("rgb_array")
    if viewer is not None:  # free its MjrContext in its own GL context, not in ours (see env.free_renderer)
        viewer.make_context_current()
        viewer.con.free()
    env.close()


@pytest.mark.parametrize("name", ["drawer-open", "pick-place", "stick-pull"])
def test_fast_rendering_shows_what_the_default_rendering_shows(name):
    ours, ref = MetaWorldEpisode(name, 3), _default_render_env(name, 3)
    camera = TASKS[name]["camera"]
    try:
        ours.reset()
        expert = _expert(name)
        for t in range(21):
            a = np.clip(expert.get_action(ours.full_obs), -1, 1)
            obs, *_ = ours.step(a)
            ref.step(a)
            if t % 10:
                continue
            f, g = obs["pixels"].astype(int), _default_frame(ref, camera).astype(int)
            assert np.abs(f - g).mean() < 15  # measured 7-9 (shadows, anti-aliased edges)
            assert (f.argmax(-1) == g.argmax(-1)).mean() > 0.97  # measured >= 0.99
            colourful_f, colourful_g = np.ptp(f, axis=-1) > 60, np.ptp(g, axis=-1) > 60  # robot, objects, goal
            iou = (colourful_f & colourful_g).sum() / (colourful_f | colourful_g).sum()
            assert iou > 0.85, iou  # measured 0.91-0.94
    finally:
        ours.close()
        _close_default(ref)


def test_closing_one_episode_leaves_another_drawing():
    """A renderer freed in another live renderer's GL context deletes that one's buffers (it then draws noise:
    under OSMesa; EGL happens to release the context first). Two tasks: episodes of one task share a renderer."""
    a, b = MetaWorldEpisode("drawer-open", 0), MetaWorldEpisode("door-open", 0)
    try:
        first, _, _ = a.reset()
        b.reset()
        a.frame(96)  # a's context is current while b closes
        b.close()
        assert np.array_equal(a.frame(96), first["pixels"])
    finally:
        a.close()


def test_episodes_of_a_task_share_one_renderer_and_draw_what_their_own_would():
    """An evaluation keeps every episode alive at once: one renderer a task and size per process, not one an episode
    (about 100-150 MB each), each frame drawn from the episode's own model and data (peg's box moves in the model)."""
    from bcbench.tasks.metaworld import env as mw

    def frames(ep):
        out = [ep.reset()[0]["pixels"]]
        for a in ([0.5, -0.3, 0.2, 1.0], [-0.2, 0.4, -0.1, -1.0]):
            out.append(ep.step(np.array(a))[0]["pixels"])
        return out

    alone = []
    for seed in (0, 1, 2):  # one at a time: each makes and frees its own renderer
        ep = MetaWorldEpisode("peg-insert-side", seed)
        alone.append(frames(ep))
        ep.close()
        assert not mw._SHARED
    eps = [MetaWorldEpisode("peg-insert-side", seed) for seed in (0, 1, 2)]
    try:
        assert len(mw._SHARED) == 1 and next(iter(mw._SHARED.values()))[1] == 3  # one renderer, three users
        together = [frames(ep) for ep in eps]
        for own, shared in zip(alone, together, strict=True):
            assert all(np.array_equal(f, g) for f, g in zip(own, shared, strict=True))
        assert not np.array_equal(together[0][0], together[1][0])  # the seeds' scenes differ
        eps[0].close()
        assert next(iter(mw._SHARED.values()))[1] == 2 and np.array_equal(eps[1].frame(96), together[1][-1])
    finally:
        for ep in eps:
            ep.close()
    assert not mw._SHARED  # the last user freed it


def test_a_machine_that_cannot_render_gets_one_line():
    env = {**os.environ, "MUJOCO_GL": "no-such-backend",
           "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    code = ("from bcbench.errors import BCBenchError\nfrom bcbench.tasks.metaworld.env import MetaWorldEpisode\n"
            "try:\n    MetaWorldEpisode('drawer-open', 0)\nexcept BCBenchError as e:\n    print('ERR', e)\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60).stdout
    assert out.startswith("ERR MetaWorld cannot render") and "MUJOCO_GL=egl" in out and out.count("\n") == 1


# ------------------------------------------------------------------ demonstrations
@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    """pick-place (the shortest expert, ~55 steps): the same arguments twice in this process, once in two
    spawned workers, and once from another seed_start; all with action noise."""
    root = tmp_path_factory.mktemp("mw")
    runs = {"a": dict(seed_start=0, workers=1), "a_again": dict(seed_start=0, workers=1),
            "a_pool": dict(seed_start=0, workers=2), "b": dict(seed_start=10, workers=1)}
    out = {}
    for key, kw in runs.items():
        summary = generate("pick-place", 2, root / f"{key}.zarr", noise=0.1, progress=False, **kw)
        out[key] = (root / f"{key}.zarr", summary)
    return out


def _arrays(path: Path) -> dict[str, np.ndarray]:
    import zarr

    root = zarr.open_group(str(path), mode="r")
    return {k: np.asarray(root[k][:]) for k in ("data/img", "data/state", "data/action", "meta/episode_ends",
                                                 "meta/seeds")}


def test_generate_is_reproducible_and_seed_start_matters(stores):
    a = _arrays(stores["a"][0])
    for other in ("a_again", "a_pool"):
        b = _arrays(stores[other][0])
        for key in a:
            assert a[key].dtype == b[key].dtype and np.array_equal(a[key], b[key]), (other, key)
    c = _arrays(stores["b"][0])
    assert c["meta/seeds"].min() >= 10 and not np.array_equal(a["data/action"][:50], c["data/action"][:50])


def test_store_round_trips_through_the_reader(stores):
    path, summary = stores["a"]
    buf = load_metaworld_buffer(path)
    task = metaworld_task("pick-place")
    assert buf.images is not None and buf.images.dtype == np.uint8
    assert buf.images.shape == (summary["steps"], 96, 96, 3)
    assert buf.state.shape == (summary["steps"], task.state_dim) and buf.action.shape == (summary["steps"], 4)
    assert buf.n_episodes == 2 and buf.keypoint is None and buf.n_contacts is None
    assert np.abs(buf.action).max() <= 1.0
    info = store_info(path)
    assert info["task"] == "metaworld/pick-place" and info["kept"] == 2 and info["seeds"] == [0, 1]
    assert info["generator"]["noise"] == 0.1 and info["versions"]["metaworld"] == "3.1.1"
    assert load_metaworld_buffer(path, images=False).images is None
    # the first recorded step is the seed's start: the observation before the first action
    ep = MetaWorldEpisode("pick-place", 0)
    try:
        obs, _, _ = ep.reset()
        assert np.array_equal(buf.images[0], obs["pixels"]) and np.array_equal(buf.state[0], obs["agent_pos"])
    finally:
        ep.close()


def test_a_larger_frames_store_records_the_same_episodes_and_is_not_the_96_px_tasks(stores, tmp_path):
    """The expert acts on state, so at 128 px the same seeds and noise give the same states and actions; only the
    frames differ. Each task's loader refuses the other's store (a frame size is part of the task)."""
    out = tmp_path / "big.zarr"
    generate("pick-place@128", 2, out, noise=0.1, progress=False, workers=1)
    small, big = _arrays(stores["a"][0]), _arrays(out)
    for key in ("data/state", "data/action", "meta/episode_ends", "meta/seeds"):
        assert np.array_equal(small[key], big[key]), key
    assert big["data/img"].shape == (len(big["data/state"]), 128, 128, 3)
    info = store_info(out)
    assert info["task"] == "metaworld/pick-place@128" and info["generator"]["image_size"] == 128
    buf = get_task("metaworld/pick-place@128").load_buffer(out, True)
    assert buf.images.shape[1:] == (128, 128, 3)
    theirs = "holds demonstrations of metaworld/pick-place, not metaworld/pick-place@128"
    with pytest.raises(DatasetError, match=re.escape(theirs)):
        get_task("metaworld/pick-place@128").load_buffer(stores["a"][0], True)
    with pytest.raises(DatasetError, match=re.escape("of metaworld/pick-place@128, not metaworld/pick-place") + "$"):
        get_task("metaworld/pick-place").load_buffer(out, True)


def test_reader_refuses_a_bad_store(tmp_path):
    import zarr

    with pytest.raises(DatasetError, match="not a folder"):
        load_metaworld_buffer(tmp_path / "missing.zarr")
    root = zarr.open_group(str(tmp_path / "bad.zarr"), mode="w", zarr_format=2)
    root.create_array("data/img", shape=(3, 84, 84, 3), dtype=np.uint8)
    for key, shape, dtype in (("data/state", (3, 4), np.float32), ("data/action", (3, 4), np.float32),
                              ("meta/episode_ends", (1,), np.int64), ("meta/seeds", (1,), np.int64)):
        root.create_array(key, shape=shape, dtype=dtype)
    with pytest.raises(DatasetError, match=re.escape("data/img is uint8 (3, 84, 84, 3), expected")):
        load_metaworld_buffer(tmp_path / "bad.zarr")


@pytest.mark.parametrize("seed_start,episodes", [(100_000 - 5, 3), (100_050, 1), (199_990, 5), (-1, 1)])
def test_generate_refuses_test_and_validation_seeds(tmp_path, seed_start, episodes):
    with pytest.raises(BCBenchError, match="seed"):
        generate("pick-place", episodes, tmp_path / "x.zarr", seed_start=seed_start, progress=False)
    assert not (tmp_path / "x.zarr").exists()


def test_dataset_paths(tmp_path, monkeypatch, stores):
    task = metaworld_task("pick-place")
    with pytest.raises(DatasetError, match="not found"):
        task.dataset(str(tmp_path / "nowhere.zarr"))
    monkeypatch.setenv("BCBENCH_HOME", str(tmp_path))
    with pytest.raises(DatasetError, match="bcbench data generate --task metaworld/pick-place --episodes N"):
        task.dataset(None)
    assert task.dataset(str(stores["a"][0])) == stores["a"][0]
    with pytest.raises(BCBenchError, match="already exists"):
        generate("pick-place", 1, stores["a"][0], progress=False)


def test_a_new_machine_generates_a_missing_store_from_its_record_and_checks_it(stores, tmp_path, monkeypatch,
                                                                                capsys):
    """scripts/demo_records.py --ensure (scripts/cpu_study.sh runs it): a store missing from the task's default
    place is generated with its record's settings and must equal the record byte for byte; a store that differs
    from its record stops the study in one line, exit 2."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("demo_records", Path(SRC).parent / "scripts" / "demo_records.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    records = tmp_path / "records"
    records.mkdir()
    rec = mod.record("metaworld/pick-place", stores["a"][0])  # seed_start 0, noise 0.1, 2 kept
    (records / "pick-place.json").write_text(json.dumps(rec))
    monkeypatch.setenv("BCBENCH_HOME", str(tmp_path / "home"))
    made = mod.ensure(records, "metaworld/pick-place", progress=False)
    assert made.startswith("metaworld/pick-place: generated") and "2 episodes" in made
    mine, theirs = _arrays(tmp_path / "home/data/metaworld/pick-place.zarr"), _arrays(stores["a"][0])
    assert all(np.array_equal(mine[k], theirs[k]) for k in theirs)
    assert mod.ensure(records, "metaworld/pick-place", progress=False).startswith("metaworld/pick-place: found")
    rec["arrays_sha256"]["data/action"] = "0" * 64
    (records / "pick-place.json").write_text(json.dumps(rec))
    assert mod.main(["--ensure", str(records), "metaworld/pick-place"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "data/action differ from" in err and "found here" in err
    assert mod.main(["--ensure", str(records), "metaworld/door-open"]) == 2
    assert "no record" in capsys.readouterr().err
