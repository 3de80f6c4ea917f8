"""The LeRobot worker: runs in the LeRobot sidecar's Python (`make lerobot-env`), never in bcbench's.

LeRobot 0.6.1 needs Python >= 3.12, torch < 2.12 and diffusers < 0.40, so it cannot share bcbench's
environment. bcbench's adapter (`bcbench.policies.lerobot_policy`) starts this file as a script in the sidecar
and asks it for action chunks over a pipe. Only the standard library and numpy are imported at module level,
so bcbench's own tests import the framing (`send`, `receive`) and a stand-in worker speaks the same protocol.

Protocol: each message is a 4-byte little-endian header length, a JSON header, then the raw bytes of the arrays
the header lists ({"name", "dtype", "shape"}, C order). Requests and replies:
    {"op": "load", "path", "threads", "steps"} -> {"ok", "kind", "obs_horizon", "pred_horizon", "action_horizon",
                                                   "chunk_start", "config", "versions"}
    {"op": "predict"} + image uint8 (B, To, 96, 96, 3), agent_pos float32 (B, To, 2), seeds int64 (B,)
        -> {"ok", "compute_s"} + actions float32 (B, pred_horizon, 2) in pixels
    {"op": "model_input"} + image, agent_pos -> what the model's forward receives after LeRobot's preprocessing
    {"op": "quit"} -> {"ok"}
A failure is {"ok": false, "error": "one line"}; the worker then waits for the next request.

Observations go through LeRobot's own path, the one `lerobot_eval.py` uses with gym-pusht:
`preprocess_observation({"pixels", "agent_pos"})` (uint8 HWC -> float [0, 1] CHW) and the saved preprocessor
(normalisation), one time step at a time as `select_action` queues them, then stacked over To.
Diffusion Policy's `select_action` returns only `n_action_steps` actions from the current step; bcbench needs
the whole horizon from the oldest observation (chunk_start = n_obs_steps - 1), so the worker calls the model's
conditional sampling itself: `diffusion._prepare_global_conditioning` and `diffusion.conditional_sample`,
private in LeRobot 0.6.1 (pinned by `make lerobot-env`; the sidecar test checks them). ACT's public
`predict_action_chunk` returns its whole chunk.
"""

from __future__ import annotations

import json
import os
import struct
import sys
import time
from typing import Any, BinaryIO

import numpy as np

LEROBOT_VERSION = "0.6.1"


def send(stream: BinaryIO, header: dict[str, Any], arrays: dict[str, np.ndarray] | None = None) -> None:
    arrays = {k: np.ascontiguousarray(v) for k, v in (arrays or {}).items()}
    head = {**header, "arrays": [{"name": k, "dtype": str(v.dtype), "shape": list(v.shape)} for k, v in arrays.items()]}
    raw = json.dumps(head).encode()
    stream.write(struct.pack("<I", len(raw)) + raw)
    for v in arrays.values():
        stream.write(v.tobytes())
    stream.flush()


def _read_exact(stream: BinaryIO, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = stream.read(n - len(buf))
        if not chunk:
            raise EOFError("the other side closed the pipe")
        buf += chunk
    return buf


def receive(stream: BinaryIO) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    (n,) = struct.unpack("<I", _read_exact(stream, 4))
    header = json.loads(_read_exact(stream, n))
    arrays = {}
    for spec in header.pop("arrays", []):
        dtype, shape = np.dtype(spec["dtype"]), tuple(spec["shape"])
        size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        arrays[spec["name"]] = np.frombuffer(_read_exact(stream, size), dtype=dtype).reshape(shape)
    return header, arrays


class Engine:
    """A LeRobot policy folder loaded with its processors, answering chunk requests."""

    def __init__(self, path: str, threads: int | None = None, steps: int | None = None) -> None:
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        if threads:
            torch.set_num_threads(threads)
        self.torch = torch
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = "cpu"
        if cfg.type not in ("diffusion", "act"):
            raise ValueError(f"policy type '{cfg.type}': this worker runs LeRobot's diffusion and act")
        self.policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
        self.policy.eval()
        if steps and cfg.type == "diffusion":
            self.policy.diffusion.num_inference_steps = steps
        cpu = {"device_processor": {"device": "cpu"}}
        self.pre, self.post = make_pre_post_processors(cfg, pretrained_path=path, preprocessor_overrides=cpu,
                                                       postprocessor_overrides=cpu)
        self.cfg = cfg
        diffusion = cfg.type == "diffusion"
        self.info = {"kind": cfg.type, "obs_horizon": cfg.n_obs_steps,
                     "pred_horizon": cfg.horizon if diffusion else cfg.chunk_size,
                     "action_horizon": cfg.n_action_steps, "chunk_start": cfg.n_obs_steps - 1 if diffusion else 0,
                     "config": self._config_summary(), "versions": self._versions()}

    def _config_summary(self) -> dict[str, Any]:
        c = self.cfg
        keys = ("n_obs_steps", "horizon", "chunk_size", "n_action_steps", "noise_scheduler_type",
                "num_train_timesteps", "vision_backbone", "crop_shape", "down_dims", "dim_model", "use_vae")
        out = {k: getattr(c, k) for k in keys if hasattr(c, k)}
        if c.type == "diffusion":
            out["num_inference_steps"] = self.policy.diffusion.num_inference_steps
        out["parameters"] = sum(p.numel() for p in self.policy.parameters())
        return json.loads(json.dumps(out, default=list))

    def _versions(self) -> dict[str, str]:
        import lerobot

        return {"lerobot": lerobot.__version__, "torch": self.torch.__version__,
                "python": sys.version.split()[0]}

    def _model_batch(self, image: np.ndarray, agent_pos: np.ndarray) -> dict[str, Any]:
        """LeRobot's eval path per time step (preprocess_observation, then the saved preprocessor), stacked
        over the window as the policy's observation queues stack them: (B, To, ...) per key."""
        from lerobot.envs.utils import preprocess_observation

        steps = []
        for t in range(image.shape[1]):
            obs = preprocess_observation({"pixels": np.ascontiguousarray(image[:, t]),
                                          "agent_pos": agent_pos[:, t].astype(np.float64)})
            obs["task"] = [""] * image.shape[0]
            steps.append(self.pre(obs))
        keys = ["observation.state", *self.cfg.image_features]
        return {k: self.torch.stack([s[k] for s in steps], dim=1) for k in keys}

    def model_input(self, image: np.ndarray, agent_pos: np.ndarray) -> dict[str, np.ndarray]:
        return {k: v.numpy() for k, v in self._model_batch(image, agent_pos).items()}

    def predict(self, image: np.ndarray, agent_pos: np.ndarray, seeds: np.ndarray) -> np.ndarray:
        torch = self.torch
        with torch.inference_mode():
            batch = self._model_batch(image, agent_pos)
            if self.cfg.type == "diffusion":
                stacked = dict(batch)
                stacked["observation.images"] = torch.stack([batch[k] for k in self.cfg.image_features], dim=-4)
                diffusion = self.policy.diffusion
                cond = diffusion._prepare_global_conditioning(stacked)  # (B, global_cond_dim)
                # One noise stream per row, from the row's seed: an episode's chunk does not depend on which
                # other episodes share its batch (the DDPM steps' own noise does, at B > 1).
                shape = (self.cfg.horizon, self.cfg.action_feature.shape[0])
                noise = torch.stack([torch.randn(shape, generator=torch.Generator().manual_seed(int(s)))
                                     for s in seeds])
                gen = torch.Generator().manual_seed(int(seeds[0]))
                actions = diffusion.conditional_sample(len(seeds), global_cond=cond, noise=noise, generator=gen)
            else:  # ACT: one observation, its whole chunk
                last = {k: v[:, -1] for k, v in batch.items()}
                actions = self.policy.predict_action_chunk(last)  # (B, chunk_size, 2)
            return self.post(actions).float().numpy()  # unnormalised: pixels


def main() -> None:
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # whatever LeRobot or torch print goes to stderr; the protocol owns the pipe
    inp = sys.stdin.buffer
    engine: Engine | None = None
    while True:
        try:
            header, arrays = receive(inp)
        except EOFError:
            return
        op = header.get("op")
        try:
            if op == "load":
                engine = Engine(header["path"], header.get("threads"), header.get("steps"))
                send(out, {"ok": True, **engine.info})
            elif op in ("predict", "model_input"):
                if engine is None:
                    raise RuntimeError("no policy loaded")
                if op == "model_input":
                    send(out, {"ok": True}, engine.model_input(arrays["image"], arrays["agent_pos"]))
                    continue
                t = time.perf_counter()
                actions = engine.predict(arrays["image"], arrays["agent_pos"], arrays["seeds"])
                send(out, {"ok": True, "compute_s": time.perf_counter() - t}, {"actions": actions})
            elif op == "quit":
                send(out, {"ok": True})
                return
            else:
                raise ValueError(f"unknown op {op!r}")
        except Exception as e:  # one line back to bcbench; the worker stays up for the next request
            send(out, {"ok": False, "error": f"{type(e).__name__}: {e}".splitlines()[0]})


if __name__ == "__main__":
    main()
