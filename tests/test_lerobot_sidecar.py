"""LeRobot interop against LeRobot itself: run where the sidecar exists (`make lerobot-env`), skipped elsewhere.

Randomly initialised LeRobot Diffusion Policy and ACT, saved with `save_pretrained` and their processors
(tests/sidecar/make_random_lerobot.py), evaluated by bcbench; bcbench's observation compared with what
LeRobot's own gym-pusht evaluation feeds the model; datasets written by LeRobot read by bcbench and back.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from bcbench.cli.main import main
from bcbench.data.lerobot_format import export_lerobot
from bcbench.data.lerobot_import import import_lerobot
from bcbench.policies.lerobot_policy import sidecar_python
from tests.conftest import make_synthetic_buffer

SIDE = Path(__file__).parent / "sidecar"
pytestmark = [pytest.mark.sidecar,
              pytest.mark.skipif(not sidecar_python().exists(), reason="no LeRobot sidecar (make lerobot-env)")]


def _side(*args: str) -> None:
    proc = subprocess.run([str(sidecar_python()), *args], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("lerobot")
    out = {}
    for kind in ("diffusion", "act"):
        out[kind] = root / kind
        _side(str(SIDE / "make_random_lerobot.py"), kind, str(out[kind]), "--small", "--steps", "3")
    return out


@pytest.mark.parametrize("kind", ["diffusion", "act"])
def test_bcbench_evaluates_and_times_a_lerobot_policy(kind, folders, tmp_path):
    assert main(["eval", "--policy", f"lerobot:{folders[kind]}", "--episodes", "2", "--max-steps", "24",
                 "--out", str(tmp_path / "e"), "--quiet"]) == 0
    rec = json.loads((tmp_path / "e" / "eval.json").read_text())
    assert rec["policy"]["name"] == f"lerobot-{kind}" and rec["policy"]["versions"]["lerobot"] == "0.6.1"
    assert [e["seed"] for e in rec["episodes"]] == [100000, 100001]
    assert main(["latency", "--policy", f"lerobot:{folders[kind]}", "--quick", "--out", str(tmp_path / "l")]) == 0
    row = json.loads((tmp_path / "l" / "latency.json").read_text())["rows"][0]
    assert row["median_ms"] > 0


@pytest.mark.parametrize("kind", ["diffusion", "act"])
def test_the_model_sees_what_lerobots_own_gym_pusht_evaluation_feeds_it(kind, folders, tmp_path):
    from bcbench.evaluation.controller import ChunkedController
    from bcbench.policies.outside import outside_policy
    from bcbench.tasks.pusht.env import dp_initial_state, make_env

    state, action = dp_initial_state(100003), [260.0, 240.0]
    _side(str(SIDE / "lerobot_side.py"), "observe", str(folders[kind]), json.dumps(state.tolist()),
          json.dumps(action), str(tmp_path / "lr.npz"))
    theirs = np.load(tmp_path / "lr.npz")
    policy = outside_policy(f"lerobot:{folders[kind]}")
    env = make_env()
    obs, _ = env.reset(options={"reset_to_state": state})
    ctrl = ChunkedController(policy)
    ctrl.reset(0, obs)
    for step in range(2):
        ours = policy.model_input(ctrl.stacked_obs([0]))
        for key in ("observation.image", "observation.state"):
            window = [0, 0] if step == 0 else [0, 1]  # the policy's queue: the first frame repeated, then new
            expect = np.stack([theirs[f"{key}/{t}"] for t in window[-policy.obs_horizon:]], axis=1)
            assert ours[key].shape == expect.shape and np.array_equal(ours[key], expect), (key, step)
        obs, *_ = env.step(np.asarray(action))
        ctrl.observe(0, obs)
    policy.close()


@pytest.mark.parametrize("kind", ["image", "video"])
def test_bcbench_reads_a_dataset_that_lerobot_wrote(kind, tmp_path):
    _side(str(SIDE / "lerobot_side.py"), "write-dataset", str(tmp_path / "ds"), kind)
    given = np.load(str(tmp_path / "ds") + ".npz")
    buf = import_lerobot(tmp_path / "ds")
    assert np.array_equal(buf.episode_ends, given["episode_ends"]) and buf.missing
    assert np.array_equal(buf.state[:, :2], given["state"]) and np.array_equal(buf.action, given["action"])
    if kind == "image":
        assert np.array_equal(buf.images, given["image"])
    _side(str(SIDE / "lerobot_side.py"), "read-dataset", str(tmp_path / "ds"), str(tmp_path / "read.npz"))
    assert np.array_equal(buf.images, np.load(tmp_path / "read.npz")["image"])  # as LeRobot's own decoder


@pytest.mark.parametrize("video", [False, True])
def test_lerobot_loads_what_bcbench_exports(video, tmp_path):
    buf = make_synthetic_buffer()
    buf.images = np.clip(np.rint(buf.images), 0, 255).astype(np.uint8)
    export_lerobot(buf, tmp_path / "ds", video=video)
    _side(str(SIDE / "lerobot_side.py"), "read-dataset", str(tmp_path / "ds"), str(tmp_path / "read.npz"))
    read = np.load(tmp_path / "read.npz")
    assert np.array_equal(read["state"], buf.state[:, :2]) and np.array_equal(read["action"], buf.action)
    assert np.array_equal(np.bincount(read["episode_index"]), np.diff(buf.episode_ends, prepend=0))
    assert np.array_equal(read["image"], import_lerobot(tmp_path / "ds").images)  # one decode, two readers
    if not video:
        assert np.array_equal(read["image"], buf.images)
