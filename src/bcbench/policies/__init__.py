"""The policy registry: name -> (Config class, Policy class).

Every entry's config class has `preset(name)` for the `quick` (2-core CPU) and `paper` (the study's)
sizes. Learned policies join this dict as they are written.
"""

from __future__ import annotations

from typing import Any

from bcbench.errors import BCBenchError
from bcbench.policies.baselines import BaselineConfig, RandomPolicy, ScriptedPolicy

REGISTRY: dict[str, tuple[type, type]] = {
    "random": (BaselineConfig, RandomPolicy),
    "scripted": (BaselineConfig, ScriptedPolicy),
}


def make_policy(name: str, config: str = "quick", **overrides: Any) -> Any:
    """Build a registered policy from a preset, with field overrides."""
    if name not in REGISTRY:
        raise BCBenchError(f"unknown policy '{name}' (registered: {', '.join(sorted(REGISTRY))})")
    config_cls, policy_cls = REGISTRY[name]
    cfg = config_cls.preset(config)
    if overrides:
        fields = set(cfg.__dataclass_fields__)
        bad = sorted(set(overrides) - fields)
        if bad:
            raise BCBenchError(f"unknown config field(s) for {name}: {', '.join(bad)}")
        cfg = config_cls(**{**cfg.__dict__, **overrides})
    return policy_cls(cfg)
