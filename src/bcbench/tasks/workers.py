"""A task's simulators in worker processes: episode e lives on worker e % n (bcbench.evaluation drives them).

A worker is started with multiprocessing's spawn (no fork of a process that holds torch threads), and a spawned
child imports the module its target lives in: this one imports the task's simulator and the video writer only, so a
pool starts in about a second rather than the several seconds an import of the evaluation stage (torch, the
policies) costs, once per evaluation.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
from typing import Any

import numpy as np

from bcbench.errors import BCBenchError
from bcbench.tasks import get_task
from bcbench.tasks.spec import Episode
from bcbench.tasks.video import VideoWriter


def _worker(conn: Any, task_name: str, video_size: int) -> None:
    """Own a set of episodes of one task; answer 'reset', 'step' and 'close' messages until 'stop'."""
    task = get_task(task_name)
    envs: dict[int, Episode] = {}
    videos: dict[int, VideoWriter] = {}
    try:
        while True:
            cmd, payload = conn.recv()
            if cmd == "reset":  # payload: [(episode, seed, video_path | None)]
                out = {}
                for ep, seed, video_path in payload:
                    env = task.make_episode(seed, video_size)
                    obs, progress, state = env.reset()
                    envs[ep] = env
                    if video_path:
                        videos[ep] = VideoWriter(video_path, label=f"seed {seed}")
                        videos[ep].add(env.render(), step=0, reward=0.0, score=0.0)
                    out[ep] = (obs, progress, state)
                conn.send(("ok", out))
            elif cmd == "step":  # payload: {episode: (action, score_so_far)}
                out = {}
                for ep, (action, score) in payload.items():
                    obs, reward, terminated, progress, state = envs[ep].step(np.asarray(action, dtype=np.float64))
                    if ep in videos:
                        videos[ep].add(envs[ep].render(), step=None, reward=reward, score=max(score, reward))
                    out[ep] = (obs, reward, terminated, progress, state)
                conn.send(("ok", out))
            elif cmd == "close":  # payload: [episode]
                paths = {}
                for ep in payload:
                    if ep in videos:
                        paths[ep] = videos.pop(ep).close()
                    env = envs.pop(ep, None)
                    if env is not None:
                        env.close()
                conn.send(("ok", paths))
            elif cmd == "stop":
                break
    except Exception as exc:  # report, don't hang the parent
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        for v in videos.values():
            v.close()
        conn.close()


class WorkerPool:
    """Simulator processes of one task; episode e lives on worker e % n."""

    def __init__(self, n: int, video_size: int, task: str = "pusht") -> None:
        ctx = mp.get_context("spawn")
        self.conns, self.procs = [], []
        for _ in range(n):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_worker, args=(child, task, video_size), daemon=True)
            proc.start()
            child.close()
            self.conns.append(parent)
            self.procs.append(proc)

    def call(self, cmd: str, per_worker: list[Any]) -> dict[int, Any]:
        """Send each worker its payload (None = skip), gather and merge the answers."""
        for conn, payload in zip(self.conns, per_worker, strict=True):
            if payload is not None:
                conn.send((cmd, payload))
        merged: dict[int, Any] = {}
        for conn, payload in zip(self.conns, per_worker, strict=True):
            if payload is None:
                continue
            try:
                status, out = conn.recv()
            except EOFError:
                raise BCBenchError("a simulator worker died unexpectedly") from None
            if status != "ok":
                raise BCBenchError(f"simulator worker failed: {out}")
            merged.update(out)
        return merged

    def stop(self) -> None:
        for conn in self.conns:
            with contextlib.suppress(BrokenPipeError, OSError):
                conn.send(("stop", None))
        for proc in self.procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()
