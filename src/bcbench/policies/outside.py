"""Policies from outside bcbench, on the same footing as its own: `module:factory` and plug-in packages.

Three ways to name a policy wherever bcbench takes one (`eval`, `latency`, `realtime`, study specs):

- a registered name (`scripted`, or a trained run through `--checkpoint`);
- `my_pkg.my_module:make_policy`: a factory (function or class) that returns a `bcbench.ChunkPolicy`, called
  with the keyword arguments of `--policy-arg KEY=VALUE` (values are JSON where they parse, else strings);
- the name of a plug-in: an installed package that declares an entry point in the group `bcbench.policies`
  (`knn = "bcbench_knn:make_policy"` in its pyproject.toml); `bcbench policies` lists them. `PLUGIN:ARG` passes
  ARG as the factory's first argument: bcbench's own plug-in `lerobot` takes a LeRobot policy folder so
  (`lerobot:FOLDER`, run in the LeRobot sidecar: `bcbench.policies.lerobot_policy`).

Before any episode runs, `check_contract` calls the policy once on a random batch and checks what bcbench
relies on; a violation is one line naming what is wrong (the CLI prints it and exits 2, writing nothing).
"""

from __future__ import annotations

import importlib
import json
from collections.abc import Callable
from importlib import metadata
from typing import Any

import numpy as np

from bcbench.errors import BCBenchError
from bcbench.interface import ChunkPolicy
from bcbench.tasks import task_of

ENTRY_POINT_GROUP = "bcbench.policies"
REQUIRED = ("name", "obs_horizon", "pred_horizon", "action_horizon", "chunk_start", "predict_action_chunk",
            "describe")


def is_factory_path(name: str) -> bool:
    """'pkg.module:attr' names a factory; a plain name is a registered policy or a plug-in, and 'PLUGIN:ARG' a
    plug-in with its first argument (`lerobot:FOLDER`)."""
    return ":" in name and name.partition(":")[0] not in plugins()


def plugins() -> dict[str, metadata.EntryPoint]:
    """Installed plug-ins: entry-point name -> entry point, in the group `bcbench.policies`."""
    return {ep.name: ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}


def parse_kwargs(items: list[str] | None, flag: str = "--policy-arg") -> dict[str, Any]:
    """KEY=VALUE pairs; values are JSON when they parse as JSON (numbers, lists, true), else strings."""
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise BCBenchError(f"{flag} expects KEY=VALUE, got '{item}'")
        key, raw = item.split("=", 1)
        try:
            out[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            out[key.strip()] = raw
    return out


def load_factory(name: str) -> Callable[..., Any]:
    """The factory that `pkg.module:attr` or a plug-in name points to."""
    if is_factory_path(name):
        module_name, _, attr = name.partition(":")
        try:
            module = importlib.import_module(module_name)
        except ImportError as e:
            raise BCBenchError(f"policy '{name}': cannot import module '{module_name}' ({e})") from None
        factory = getattr(module, attr, None)
        if factory is None:
            raise BCBenchError(f"policy '{name}': module '{module_name}' has no attribute '{attr}'")
    else:
        found = plugins()
        if name not in found:
            raise BCBenchError(f"unknown policy '{name}': not a registered policy, not an installed plug-in "
                               f"({', '.join(sorted(found)) or 'none installed'}), and not module:factory")
        try:
            factory = found[name].load()
        except Exception as e:  # a broken plug-in: say which
            raise BCBenchError(f"plug-in '{name}' ({found[name].value}) fails to load: {type(e).__name__}: {e}"
                               ) from None
    if not callable(factory):
        raise BCBenchError(f"policy '{name}' is not callable (a factory or a class is expected)")
    return factory


def outside_policy(name: str, kwargs: dict[str, Any] | None = None) -> ChunkPolicy:
    """Build an outside policy and check its contract; every failure is one BCBenchError line."""
    args: tuple[str, ...] = ()
    if ":" in name and not is_factory_path(name):  # PLUGIN:ARG, e.g. lerobot:FOLDER
        name, arg = name.split(":", 1)
        args = (arg,)
    factory = load_factory(name)
    try:
        policy = factory(*args, **(kwargs or {}))
    except BCBenchError:
        raise
    except Exception as e:
        raise BCBenchError(f"policy '{name}': the factory raised {type(e).__name__}: {e}") from None
    check_contract(policy, name)
    return policy


def check_contract(policy: object, source: str, batch: int = 2) -> None:
    """What bcbench relies on, checked once before any episode: attributes, horizons, and one call's output
    (shape (B, pred_horizon, A) for its task's A, a float ndarray, finite), and a JSON-ready describe()."""
    missing = [a for a in REQUIRED if not hasattr(policy, a)]
    if missing:
        raise BCBenchError(f"policy '{source}' lacks {', '.join(missing)} (the bcbench.ChunkPolicy interface)")
    horizons = {a: getattr(policy, a) for a in ("obs_horizon", "pred_horizon", "action_horizon", "chunk_start")}
    bad = [a for a, v in horizons.items() if not isinstance(v, int | np.integer) or isinstance(v, bool) or v < 0]
    if bad or min(horizons["obs_horizon"], horizons["pred_horizon"], horizons["action_horizon"]) < 1:
        raise BCBenchError(f"policy '{source}': horizons must be whole numbers (obs, pred, action >= 1, chunk_start "
                           f">= 0), got {horizons}")
    if horizons["chunk_start"] + horizons["action_horizon"] > horizons["pred_horizon"]:
        raise BCBenchError(f"policy '{source}': chunk_start + action_horizon exceeds pred_horizon ({horizons})")
    task = task_of(policy)  # a policy's `task` (a name) where it declares one, else Push-T
    obs = task.example_observation(batch, horizons["obs_horizon"])
    try:
        out = policy.predict_action_chunk(obs)
    except Exception as e:
        raise BCBenchError(f"policy '{source}': predict_action_chunk raised {type(e).__name__}: {e}") from None
    want = (batch, horizons["pred_horizon"], task.action_dim)
    if not isinstance(out, np.ndarray):
        raise BCBenchError(f"policy '{source}': predict_action_chunk must return a numpy array, got "
                           f"{type(out).__name__}")
    if out.shape != want:
        raise BCBenchError(f"policy '{source}': predict_action_chunk returned shape {out.shape}, expected {want} "
                           f"(batch, pred_horizon, {task.name}'s {task.action_dim} action values)")
    if not np.issubdtype(out.dtype, np.floating):
        raise BCBenchError(f"policy '{source}': predict_action_chunk returned dtype {out.dtype}, expected float32 "
                           "positions in pixels")
    if not np.isfinite(out).all():
        raise BCBenchError(f"policy '{source}': predict_action_chunk returned NaN or infinite values")
    try:
        json.dumps(policy.describe())
    except Exception as e:
        raise BCBenchError(f"policy '{source}': describe() must return a JSON-ready dict ({type(e).__name__}: {e})"
                           ) from None
