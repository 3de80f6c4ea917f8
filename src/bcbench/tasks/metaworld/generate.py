"""Scripted demonstrations for a MetaWorld task: MetaWorld's own expert (`metaworld.policies`), one seed an
episode, only successful episodes kept, written as one zarr v2 store (`reader.py` reads it).

Why this shape:
- Seeds seed_start, seed_start + 1, ... are tried in order and the first `episodes` successes kept, so that the
  store depends on (task, episodes, seed_start, noise) only, never on how many workers ran or which finished
  first: same arguments, byte-identical arrays.
- A step records the observation before the action (frame and proprioception) and the action executed: the
  expert's, plus Gaussian noise of std `noise` (drawn from a generator seeded with the episode's seed), clipped
  to [-1, 1]. What a policy is trained on is what the simulator was given.
- Demonstration seeds never touch the test seeds (100000-100099) or the validation seeds (200000+): a policy
  must not have seen the starts it is scored on.
- One environment per worker process serves all its seeds (a renderer costs about 0.5 s to make).
"""

from __future__ import annotations

import datetime
import multiprocessing as mp
import os
import time
import warnings
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from bcbench.errors import BCBenchError
from bcbench.protocol import TEST_EPISODES, TEST_SEED_START, VALIDATION_SEED_START, overlaps_test_seeds
from bcbench.tasks.metaworld.reader import FORMAT
from bcbench.tasks.metaworld.table import CAMERA, CONTROL_HZ, TASKS, split_name, state_names

MAX_ATTEMPTS_PER_EPISODE = 4  # give up when the expert would need more than 4 tries per kept episode
IMG_CHUNK = 100  # steps per image chunk (about 2.8 MB raw)


def check_seed_range(seed_start: int, episodes: int) -> int:
    """The most seeds generate may try (4 per episode), after refusing a range that could reach the test or
    validation seeds."""
    if episodes < 1:
        raise BCBenchError(f"need episodes >= 1, got {episodes}")
    attempts = MAX_ATTEMPTS_PER_EPISODE * episodes
    last = seed_start + attempts - 1
    if seed_start < 0:
        raise BCBenchError(f"seed_start must be >= 0, got {seed_start}")
    if overlaps_test_seeds(seed_start, attempts) or last >= VALIDATION_SEED_START:
        raise BCBenchError(
            f"demonstration seeds {seed_start}..{last} (up to {MAX_ATTEMPTS_PER_EPISODE} tries per episode) would "
            f"reach the test seeds {TEST_SEED_START}-{TEST_SEED_START + TEST_EPISODES - 1} or the validation "
            f"seeds {VALIDATION_SEED_START}+; choose a seed_start whose range avoids them")
    return attempts


class _Runner:
    """One task's environment and expert, kept for every seed this process runs."""

    def __init__(self, name: str) -> None:
        from bcbench.tasks.metaworld.env import MetaWorldEpisode

        base, size = split_name(name)  # the expert acts on state: a frame size changes only what is recorded
        self.episode = MetaWorldEpisode(base, 0, image_size=size)  # first: a MuJoCo that cannot load is one line
        import metaworld.policies as policies

        self.expert = getattr(policies, TASKS[base]["expert"])()
        self.max_steps = int(TASKS[base]["max_steps"])

    def run(self, seed: int, noise: float) -> dict[str, Any]:
        """One expert episode: {"seed", "success", "length"} and, when it succeeded, its arrays."""
        ep = self.episode
        obs, _, _ = ep.reset(seed=seed)
        rng = np.random.default_rng(seed)
        imgs, states, actions = [], [], []
        success = False
        with warnings.catch_warnings():  # the experts warn on every large gain ("Constant(s) may be too high")
            warnings.simplefilter("ignore")
            for _ in range(self.max_steps):
                a = np.asarray(self.expert.get_action(ep.full_obs), dtype=np.float64)  # (4,)
                if noise > 0:
                    a = a + rng.normal(0.0, noise, size=4)
                a = np.clip(a, -1.0, 1.0).astype(np.float32)
                imgs.append(obs["pixels"])
                states.append(obs["agent_pos"])
                actions.append(a)
                obs, _, success, _, _ = ep.step(a)
                if success:
                    break
        out: dict[str, Any] = {"seed": seed, "success": success, "length": len(actions)}
        if success:
            out.update(img=np.stack(imgs), state=np.stack(states).astype(np.float32),  # (T,H,W,3), (T,S)
                       action=np.stack(actions))  # (T,4)
        return out

    def close(self) -> None:
        self.episode.close()


_RUNNER: _Runner | None = None  # a worker process's runner


def _run_in_worker(job: tuple[str, int, float]) -> dict[str, Any]:
    """A pool task. The runner is made by the first task, not by a pool initializer: an initializer that raises
    (no EGL in the worker) makes the pool respawn workers forever, while a task's error reaches the caller."""
    global _RUNNER
    name, seed, noise = job
    if _RUNNER is None:
        import atexit

        _RUNNER = _Runner(name)
        atexit.register(_RUNNER.close)  # free the GL contexts before EGL is torn down at exit
    return _RUNNER.run(seed, noise)


def _results(name: str, seeds: range, noise: float, workers: int) -> Iterator[dict[str, Any]]:
    """Each seed's episode, in seed order (a pool's results are reordered by imap)."""
    if workers <= 1:  # in this process: no start-up cost (tests, small runs)
        runner = _Runner(name)
        try:
            for s in seeds:
                yield runner.run(s, noise)
        finally:
            runner.close()
        return
    pool = mp.get_context("spawn").Pool(workers)
    try:
        yield from pool.imap(_run_in_worker, [(name, s, noise) for s in seeds], chunksize=1)
    finally:
        pool.terminate()  # the seeds still queued are not needed
        pool.join()


def _versions() -> dict[str, str | None]:
    from bcbench.utils.system import git_commit

    out: dict[str, str | None] = {}
    for pkg in ("metaworld", "mujoco", "numpy", "zarr"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    out["bcbench_commit"] = git_commit()
    return out


def _write_store(out: Path, kept: list[dict[str, Any]], attrs: dict[str, Any], force: bool) -> None:
    """The store, written in a temporary folder beside `out` and renamed onto it when complete."""
    import numcodecs
    import zarr

    from bcbench.utils.io import atomic_dir

    comp = numcodecs.Blosc(cname="zstd", clevel=5, shuffle=numcodecs.Blosc.BITSHUFFLE)  # floats
    comp_img = numcodecs.Blosc(cname="zstd", clevel=6, shuffle=numcodecs.Blosc.NOSHUFFLE)  # 11x on frames (bit: 7x)
    arrays = {
        "data/img": np.concatenate([k["img"] for k in kept]),  # (N, 96, 96, 3) uint8
        "data/state": np.concatenate([k["state"] for k in kept]),  # (N, S) float32
        "data/action": np.concatenate([k["action"] for k in kept]),  # (N, 4) float32
        "meta/episode_ends": np.cumsum([k["length"] for k in kept]).astype(np.int64),  # (E,)
        "meta/seeds": np.array([k["seed"] for k in kept], dtype=np.int64),  # (E,)
    }
    with atomic_dir(out, force=force) as staged:
        root = zarr.open_group(str(staged), mode="w", zarr_format=2)
        for key, data in arrays.items():
            img = key == "data/img"
            chunks = (IMG_CHUNK, *data.shape[1:]) if img else data.shape
            a = root.create_array(key, shape=data.shape, chunks=chunks, dtype=data.dtype,
                                  compressors=comp_img if img else comp)
            a[:] = data
        root.attrs.update(attrs)


def generate(name: str, episodes: int, out: str | Path, *, seed_start: int = 0, noise: float = 0.0,
             workers: int | None = None, progress: bool = True, force: bool = False) -> dict[str, Any]:
    """Run the scripted expert on seeds seed_start, seed_start + 1, ... until `episodes` succeed; write them to
    `out` (a zarr v2 folder; an existing one needs `force`). Returns a summary (counts, success rate, timing)."""
    from tqdm import tqdm

    base, size = split_name(name)
    if not noise >= 0:
        raise BCBenchError(f"noise is a standard deviation: need noise >= 0, got {noise}")
    out = Path(out)
    if out.exists() and not force:
        raise BCBenchError(f"{out} already exists; pass --force to replace it")
    attempts = check_seed_range(seed_start, episodes)
    workers = max(1, min(workers or os.cpu_count() or 1, attempts))
    kept: list[dict[str, Any]] = []
    failed: list[int] = []
    t0 = time.perf_counter()
    bar = tqdm(total=episodes, desc=f"metaworld/{name} demonstrations", unit="episode", disable=not progress)
    results = _results(name, range(seed_start, seed_start + attempts), noise, workers)
    try:
        for i, r in enumerate(results, 1):
            if r["success"]:
                kept.append(r)
                bar.update(1)
            else:
                failed.append(int(r["seed"]))
            bar.set_postfix(tried=i)
            if len(kept) == episodes:
                break
            if len(kept) + attempts - i < episodes:
                raise BCBenchError(
                    f"metaworld/{name}: the scripted expert succeeded in {len(kept)} of {i} episodes (cap "
                    f"{TASKS[base]['max_steps']} steps{f', noise {noise:g}' if noise else ''}): {episodes} "
                    f"successes cannot come within {attempts} tries; lower the noise or ask for fewer")
    finally:
        results.close()  # stops the pool (or closes this process's environment)
        bar.close()
    attempted = len(kept) + len(failed)
    seconds = time.perf_counter() - t0
    attrs = {
        "format": FORMAT, "task": f"metaworld/{name}", "env": TASKS[base]["env"], "expert": TASKS[base]["expert"],
        "generator": {"seed_start": seed_start, "noise": noise, "noise_is": "std of Gaussian noise added to the "
                      "expert's action before clipping to [-1, 1], drawn from default_rng(seed)",
                      "camera": CAMERA, "image_size": size, "max_steps": int(TASKS[base]["max_steps"]),
                      "control_hz": CONTROL_HZ, "state_names": list(state_names(base))},
        "attempted": attempted, "kept": len(kept), "scripted_success_rate": len(kept) / attempted,
        "failed_seeds": failed, "versions": _versions(),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    _write_store(out, kept, attrs, force)
    steps = int(sum(k["length"] for k in kept))
    return {"path": str(out), "task": attrs["task"], "episodes": len(kept), "attempted": attempted,
            "scripted_success_rate": attrs["scripted_success_rate"], "failed_seeds": failed, "steps": steps,
            "seconds": round(seconds, 2), "episodes_per_s": round(len(kept) / seconds, 3), "workers": workers}
