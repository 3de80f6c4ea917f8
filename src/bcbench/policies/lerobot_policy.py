"""LeRobot policies in bcbench: a `bcbench.ChunkPolicy` that drives a LeRobot worker in the sidecar environment.

    bcbench eval --policy lerobot:FOLDER            (shorthand for --policy lerobot --policy-arg path=FOLDER)
    bcbench latency --policy lerobot --policy-arg path=FOLDER --policy-arg steps=10

FOLDER is what LeRobot's `save_pretrained` and training script write: config.json, model.safetensors and the
pre/post-processor files (policy_preprocessor.json, policy_postprocessor.json and their .safetensors). The
worker (`bcbench.policies.lerobot_worker`) runs in the sidecar's Python, `make lerobot-env` makes it
(.lerobot-venv beside this repo; $BCBENCH_LEROBOT_PYTHON names another). It reports its own compute time for
every call, so latency records exclude the pipe (`SelfTimedPolicy`).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.errors import BCBenchError
from bcbench.interface import Observation
from bcbench.policies import lerobot_worker
from bcbench.policies.lerobot_worker import receive, send

PYTHON_ENV = "BCBENCH_LEROBOT_PYTHON"
SIDECAR = Path(__file__).resolve().parents[3] / ".lerobot-venv"  # src/bcbench/policies -> repo root
PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")


def sidecar_python() -> Path:
    """The sidecar's interpreter: $BCBENCH_LEROBOT_PYTHON, else .lerobot-venv beside the repo."""
    return Path(os.environ[PYTHON_ENV]) if os.environ.get(PYTHON_ENV) else SIDECAR / "bin" / "python"


def check_folder(path: Path) -> None:
    """A LeRobot policy folder as LeRobot >= 0.4 saves it; an older one (normalisation inside the model, no
    processor files) gets the migration command."""
    if not path.is_dir():
        raise BCBenchError(f"LeRobot policy folder {path} does not exist")
    missing = [f for f in ("config.json", "model.safetensors") if not (path / f).is_file()]
    if missing:
        raise BCBenchError(f"{path} is not a LeRobot policy folder (no {', '.join(missing)})")
    if not all((path / f).is_file() for f in PROCESSOR_FILES):
        raise BCBenchError(f"{path} has no pre/post-processor files (an old-format LeRobot checkpoint): migrate it "
                           f"with `{sidecar_python()} -m lerobot.processor.migrate_policy_normalization "
                           f"--pretrained-path {path}`")


class LeRobotPolicy:
    """A LeRobot Diffusion Policy or ACT folder, answering through a worker process."""

    def __init__(self, path: str | os.PathLike[str], steps: int | None = None, threads: int | None = None,
                 python: str | None = None, worker: str | None = None, seed: int = 0) -> None:
        self.path = Path(path).resolve()
        check_folder(self.path)
        exe = Path(python) if python else sidecar_python()
        if not exe.exists():
            raise BCBenchError(f"LeRobot sidecar not found ({exe}): run `make lerobot-env` (or set {PYTHON_ENV})")
        script = worker or lerobot_worker.__file__
        # the worker's stderr (LeRobot's warnings) goes to a file: its last line explains a crash
        self._log = tempfile.NamedTemporaryFile(prefix="bcbench-lerobot-", suffix=".log", delete=False)  # noqa: SIM115
        # -P: the script's folder (bcbench's policies) must not shadow LeRobot's own modules
        self._proc = subprocess.Popen([str(exe), "-P", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=self._log)
        self.noise_seed = seed
        self.last_compute_s = 0.0
        self._calls = 0
        info = self._ask({"op": "load", "path": str(self.path), "threads": threads or torch.get_num_threads(),
                          "steps": steps})[0]
        self.kind: str = info["kind"]
        self.name = f"lerobot-{self.kind}"
        self.obs_horizon, self.pred_horizon = int(info["obs_horizon"]), int(info["pred_horizon"])
        self.action_horizon, self.chunk_start = int(info["action_horizon"]), int(info["chunk_start"])
        self.config: dict[str, Any] = info.get("config", {})
        self.versions: dict[str, str] = info.get("versions", {})

    def _ask(self, header: dict[str, Any], arrays: dict[str, np.ndarray] | None = None
             ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        assert self._proc.stdin is not None and self._proc.stdout is not None
        try:
            send(self._proc.stdin, header, arrays)
            reply, out = receive(self._proc.stdout)
        except (EOFError, BrokenPipeError, OSError):
            raise BCBenchError(f"the LeRobot worker stopped ({self._last_log_line()})") from None
        if not reply.get("ok"):
            raise BCBenchError(f"LeRobot worker, {header['op']} {self.path}: {reply.get('error')}")
        return reply, out

    def _last_log_line(self) -> str:
        self._proc.poll()
        lines = [ln for ln in Path(self._log.name).read_text(errors="replace").splitlines() if ln.strip()]
        return lines[-1].strip() if lines else f"exit code {self._proc.returncode}"

    def _seeds(self, obs: Observation) -> np.ndarray:
        """One seed per row: drawn from the controller's per-episode generator where it gives one, so an
        episode's noise does not depend on its batch; else from the policy's seed and a call counter."""
        gens = obs.get("generators")
        b = obs["image"].shape[0]
        if gens is not None:
            return np.array([int(torch.randint(0, 2**62, (1,), generator=g)) for g in gens], dtype=np.int64)
        self._calls += 1
        return np.random.default_rng([self.noise_seed, self._calls]).integers(0, 2**62, size=b, dtype=np.int64)

    def _arrays(self, obs: Observation) -> dict[str, np.ndarray]:
        return {"image": np.asarray(obs["image"], dtype=np.uint8),
                "agent_pos": np.asarray(obs["agent_pos"], dtype=np.float32)}

    def predict_action_chunk(self, obs: Observation) -> np.ndarray:
        reply, out = self._ask({"op": "predict"}, {**self._arrays(obs), "seeds": self._seeds(obs)})
        self.last_compute_s = float(reply["compute_s"])
        return np.asarray(out["actions"], dtype=np.float32)

    def model_input(self, obs: Observation) -> dict[str, np.ndarray]:
        """What the LeRobot model receives for `obs` after LeRobot's own preprocessing (for checks)."""
        return self._ask({"op": "model_input"}, self._arrays(obs))[1]

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "source": "lerobot", "path": str(self.path), "noise_seed": self.noise_seed,
                "parameters": int(self.config.get("parameters", 0)),
                "config": self.config, "versions": self.versions,
                "timing": "compute time reported by the worker (the pipe excluded)"}

    def close(self) -> None:
        if self._proc.poll() is None:
            with contextlib.suppress(BCBenchError):
                self._ask({"op": "quit"})
            try:
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
        self._log.close()
        Path(self._log.name).unlink(missing_ok=True)

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

