"""A stand-in for the LeRobot worker (CI has no sidecar): the same protocol and framing as
`bcbench.policies.lerobot_worker`, numpy only. The policy folder's config.json says how it behaves:
    {"type": "diffusion" | "act", "compute_s": 0.0123, "crash_on_predict": false}
It returns chunks that hold the last agent position plus a seed-dependent offset, and reports `compute_s` as its
compute time, so a test can tell the reported time from the wall time of the pipe."""

import json
import sys
from pathlib import Path

import numpy as np

from bcbench.policies.lerobot_worker import receive, send


def main() -> None:
    out, inp = sys.stdout.buffer, sys.stdin.buffer
    cfg: dict = {}
    while True:
        try:
            header, arrays = receive(inp)
        except EOFError:
            return
        op = header["op"]
        if op == "load":
            cfg = json.loads((Path(header["path"]) / "config.json").read_text())
            if cfg.get("type") not in ("diffusion", "act"):
                send(out, {"ok": False, "error": f"ValueError: policy type '{cfg.get('type')}'"})
                continue
            dp = cfg["type"] == "diffusion"
            send(out, {"ok": True, "kind": cfg["type"], "obs_horizon": 2 if dp else 1, "pred_horizon": 16,
                       "action_horizon": 8, "chunk_start": 1 if dp else 0, "config": {"stand_in": True},
                       "versions": {"lerobot": "stand-in"}})
        elif op == "predict":
            if cfg.get("crash_on_predict"):
                print("RuntimeError: the stand-in crashed on purpose", file=sys.stderr, flush=True)
                sys.exit(3)
            pos, seeds = arrays["agent_pos"], arrays["seeds"]
            offset = (seeds % 7).astype(np.float32)[:, None, None]
            actions = np.repeat(pos[:, -1:, :], 16, axis=1) + offset
            send(out, {"ok": True, "compute_s": cfg.get("compute_s", 0.0123)}, {"actions": actions.astype(np.float32)})
        elif op == "model_input":
            send(out, {"ok": True}, {"observation.image": arrays["image"].astype(np.float32) / 255})
        elif op == "quit":
            send(out, {"ok": True})
            return


if __name__ == "__main__":
    main()
