"""Run in the LeRobot sidecar (.lerobot-venv): what LeRobot itself does, for bcbench's sidecar tests to compare.

    observe POLICY_DIR STATE_JSON ACTION_JSON OUT.npz
        LeRobot's own evaluation path on gym-pusht (`make_env(PushtEnv())`, `preprocess_observation`, the env
        and policy preprocessors, as `lerobot_eval.rollout` calls them) at a simulator state and after one step;
        writes the preprocessed tensors per step.
    write-dataset OUT_DIR {image,video}
        a small Push-T-shaped dataset written by LeRobot's own LeRobotDataset.create/add_frame/save_episode;
        also writes OUT_DIR.npz with the arrays it was given.
    read-dataset DIR OUT.npz
        every frame, agent position and action of a dataset as LeRobotDataset loads them (PyAV decoder).
"""

import json
import sys
from pathlib import Path

import numpy as np
import torch


def observe(policy_dir: str, state: list, action: list, out: str) -> None:
    import gym_pusht.envs.pusht as gp
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.configs import PushtEnv
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.envs.utils import preprocess_observation
    from lerobot.policies.factory import make_pre_post_processors

    def angle_first(self, s):  # the demonstrations' reset order (bcbench.tasks.pusht.env explains it)
        s = np.asarray(s, dtype=np.float64).tolist()
        self.agent.position = s[:2]
        self.block.angle = s[4]
        self.block.position = s[2:4]
        self.space.step(self.dt)

    gp.PushTEnv._set_state = angle_first
    env_cfg = PushtEnv()
    venv = next(iter(next(iter(make_env(env_cfg, n_envs=1).values())).values()))
    cfg = PreTrainedConfig.from_pretrained(policy_dir)
    cfg.device = "cpu"
    pre, _ = make_pre_post_processors(cfg, pretrained_path=policy_dir,
                                      preprocessor_overrides={"device_processor": {"device": "cpu"}})
    env_pre, _ = make_env_pre_post_processors(env_cfg, cfg)
    obs, _ = venv.reset(seed=0, options={"reset_to_state": state})
    saved = {}
    for step in range(2):
        o = preprocess_observation(obs)
        o["task"] = [""]
        o = pre(env_pre(o))
        for k in ("observation.image", "observation.state"):
            saved[f"{k}/{step}"] = o[k].numpy()
        if step == 0:
            obs, *_ = venv.step(np.asarray([action], dtype=np.float32))
    np.savez(out, **saved)


def write_dataset(out: str, kind: str) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    feats = {"observation.image": {"dtype": kind, "shape": (96, 96, 3), "names": ["height", "width", "channel"]},
             "observation.state": {"dtype": "float32", "shape": (2,), "names": {"motors": ["x", "y"]}},
             "action": {"dtype": "float32", "shape": (2,), "names": {"motors": ["x", "y"]}},
             "next.reward": {"dtype": "float32", "shape": (1,), "names": None}}
    ds = LeRobotDataset.create("local/pusht", fps=10, features=feats, root=out, use_videos=kind == "video")
    rng = np.random.default_rng(0)
    arrays = {"state": [], "action": [], "image": []}
    for n in (6, 9):
        for _ in range(n):
            img = rng.integers(0, 256, (96, 96, 3), dtype=np.uint8)
            img[:, :48] = 200  # some flat area, as Push-T frames have
            pos, act = rng.uniform(0, 512, 2).astype(np.float32), rng.uniform(0, 512, 2).astype(np.float32)
            ds.add_frame({"observation.image": img, "observation.state": pos, "action": act,
                          "next.reward": np.zeros(1, np.float32), "task": "Push the T-shaped block."})
            for k, v in zip(("image", "state", "action"), (img, pos, act), strict=True):
                arrays[k].append(v)
        ds.save_episode()
    ds.finalize()
    np.savez(out + ".npz", **{k: np.stack(v) for k, v in arrays.items()}, episode_ends=np.array([6, 15]))


def read_dataset(root: str, out: str) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("local/any", root=root, video_backend="pyav")
    items = [ds[i] for i in range(len(ds))]
    image = torch.stack([it["observation.image"] for it in items])  # (N, 3, 96, 96) float [0, 1]
    np.savez(out, image=(image * 255).round().to(torch.uint8).permute(0, 2, 3, 1).numpy(),
             state=torch.stack([it["observation.state"] for it in items]).numpy(),
             action=torch.stack([it["action"] for it in items]).numpy(),
             episode_index=np.array([int(it["episode_index"]) for it in items]))


if __name__ == "__main__":
    cmd, *args = sys.argv[1:]
    if cmd == "observe":
        observe(args[0], json.loads(args[1]), json.loads(args[2]), args[3])
    elif cmd == "write-dataset":
        write_dataset(args[0], args[1])
    elif cmd == "read-dataset":
        read_dataset(args[0], args[1])
    else:
        raise SystemExit(f"unknown command {cmd}")
    print(Path(args[-1]).name)
