"""MetaWorld (v3) image tasks: a 96x96 frame from one fixed camera and the end-effector state in, end-effector
displacements and gripper effort out, at MetaWorld's 80 Hz; demonstrations come from its scripted experts
(`bcbench.tasks.metaworld.generate`).

Importing this package loads no MuJoCo: the episode (`env`) imports it when one is made, so that `get_task`
and `describe()` work where MetaWorld is not installed. It does pick MuJoCo's GL backend (EGL, headless)
unless MUJOCO_GL says otherwise: MuJoCo reads it once, when first imported, from whichever module that is.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import functools
from pathlib import Path

from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.errors import DatasetError
from bcbench.tasks.metaworld.reader import load_metaworld_buffer, store_info
from bcbench.tasks.metaworld.table import (
    CAMERA,
    CONTROL_HZ,
    IMAGE_SIZE,
    MAX_PATH_LENGTH,
    TASKS,
    split_name,
    state_names,
)
from bcbench.tasks.spec import Episode, Task

__all__ = ["TASKS", "default_dataset_path", "load_metaworld_buffer", "metaworld_task"]


def _episode(name: str, image_size: int, seed: int, video_size: int | None) -> Episode:
    from bcbench.tasks.metaworld.env import MetaWorldEpisode  # MuJoCo only where an episode runs

    return MetaWorldEpisode(name, seed, video_size, image_size=image_size)


def default_dataset_path(name: str) -> Path:
    """Where `bcbench data generate --task metaworld/NAME` writes by default: $BCBENCH_HOME or ~/.cache/bcbench,
    then data/metaworld/NAME.zarr (NAME with its frame size, e.g. pick-place@128, where it has one)."""
    from bcbench.data.paths import data_home

    return data_home() / "data" / "metaworld" / f"{name}.zarr"


def _dataset(name: str, path: str | None) -> Path:
    how = f"run `bcbench data generate --task metaworld/{name} --episodes N`"
    if path is not None:
        chosen = Path(path)
        if not chosen.is_dir():
            raise DatasetError(f"MetaWorld demonstrations not found at {chosen} (not a zarr folder); {how}")
        return chosen
    chosen = default_dataset_path(name)
    if not chosen.is_dir():
        raise DatasetError(f"no MetaWorld demonstrations for metaworld/{name} at {chosen}: {how}")
    return chosen


def _load(name: str, image_size: int, path: Path, images: bool) -> ReplayBuffer:
    """The store at `path`, refused in one line when its generator wrote another task's demonstrations (a frame
    size is part of the task: metaworld/pick-place@128's store is not pick-place's)."""
    wrote = store_info(path).get("task")
    if wrote != f"metaworld/{name}":
        raise DatasetError(f"{path} holds demonstrations of {wrote}, not metaworld/{name}")
    return load_metaworld_buffer(path, images=images, image_size=image_size)


def _notes(name: str, image_size: int) -> str:
    spec = TASKS[name]
    ok, n = spec["expert_success"]
    median, longest = spec["expert_length"]
    goal = "with" if len(spec["proprio"]) > 4 else "without"
    return (f"MetaWorld {spec['env']} (3.1.1), goal observable, object and goal drawn from the seed (env.seed); "
            f"camera {spec['camera']} flipped upright; proprioception hand xyz + gripper opening {goal} the goal "
            f"xyz; scripted expert {spec['expert']}: {ok}/{n} successes on seeds 0-{n - 1}, length median "
            f"{median:g} / max {longest}; cap {spec['max_steps']} >= 1.5x the longest (see table.py)"
            + ("" if image_size == IMAGE_SIZE else f"; frames at {image_size} px, not the family's {IMAGE_SIZE}"))


@functools.cache
def metaworld_task(name: str) -> Task:
    """The bcbench Task for MetaWorld's `name` (drawer-open, ..., or pick-place@128: the same task seen in larger
    frames); an unknown name or size is one BCBenchError."""
    base, size = split_name(name)
    spec = TASKS[base]
    return Task(
        name=f"metaworld/{name}", family="metaworld", image_size=size, camera=CAMERA,
        state_names=state_names(base), action_names=("dx", "dy", "dz", "grip"),
        action_low=(-1.0,) * 4, action_high=(1.0,) * 4,
        action_units=("end-effector displacement (x, y, z; scaled by MetaWorld's action_scale 1/100 m) and "
                      "gripper effort (-1 open, +1 close)"),
        control_hz=CONTROL_HZ, max_steps=int(spec["max_steps"]),
        score="success at any step (1/0)",
        success="MetaWorld's info['success'] (the episode ends)",
        progress="MetaWorld's shaped reward / 10 (in [0, 1]; its shaping, not always 1 at success)",
        make_episode=functools.partial(_episode, base, size), dataset=functools.partial(_dataset, name),
        load_buffer=functools.partial(_load, name, size), step_limit=MAX_PATH_LENGTH,
        action_hold=(False, False, False, True),  # while waiting: the hand stands still, the grip is kept
        state_range=(-1.0, 1.0),
        difficulty=spec["difficulty"], notes=_notes(base, size),
    )
