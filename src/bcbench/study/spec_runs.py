"""A study spec's [[run]] tables (every key documented at the top of `bcbench.study.spec`): one `RunSpec` per
training seed, with the `Variant`s it is evaluated (and swept) in, validated before anything runs; errors name the
offending [[run]] in one line. `bcbench.study.spec` reads the [study] table and checks the runs against each other.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.policies import REGISTRY, is_learned, make_config, sampler_kinds
from bcbench.policies.config import config_to_dict, key_dict
from bcbench.policies.outside import load_factory
from bcbench.protocol import MIN_CHOICE_EPISODES
from bcbench.tasks import DEFAULT_TASK

RUN_KEYS = {"policy", "preset", "config", "steps", "max_minutes", "seeds", "set", "eval", "label", "eval_every",
            "realtime", "args", "doubles", "check_episodes", "demos"}


@dataclass(frozen=True)
class Variant:
    """One evaluation setting of a trained run (sampler, steps, spacing for diffusion, else the default)."""

    sampler: str | None = None
    steps: int | None = None
    spacing: str | None = None
    strategy: str | None = None  # real-time sweeps only: the execution strategy (None: naive)

    @property
    def key(self) -> str:
        tail = "" if self.strategy in (None, "naive") else f"-{self.strategy}"
        if self.sampler is None:
            return "default" + tail
        return f"{self.sampler}{self.steps}" + ("" if self.spacing in (None, "trailing") else f"-{self.spacing}") + tail


@dataclass
class RunSpec:
    policy: str
    config: str
    seed: int
    max_minutes: float | None  # safety stop only: budgets are steps (`steps`) or epochs (`set`)
    overrides: dict[str, Any]
    variants: list[Variant]
    label: str
    eval_every: int | None = None  # rollouts every this many training steps: the learning curve
    realtime: list[Variant] = field(default_factory=list)  # variants swept under real-time execution
    args: dict[str, Any] = field(default_factory=dict)  # an outside policy's factory arguments
    doubles: str | None = None  # the label of the run whose convergence this run checks (twice its steps)
    check_episodes: int | None = None  # a doubling run's check size, where it differs from the study's
    demos: int | None = None  # train on the training split's first N demonstrations (None: all of them)

    @property
    def outside(self) -> bool:
        """A policy from outside bcbench (module:factory or a plug-in), run as it is given."""
        return self.policy not in REGISTRY

    @property
    def learned(self) -> bool:
        return is_learned(self.policy)

    def config_dict(self) -> dict[str, Any]:
        return config_to_dict(make_config(self.policy, self.config, {**self.overrides, "seed": self.seed}))

    def key(self, val_fraction: float, task: str = DEFAULT_TASK) -> str:
        """policy-config-sSEED-HASH: the hash covers the task, the full config, the split and the demonstration
        count, so a change retrains (Push-T, all demonstrations and a newer field at its neutral value, `KEY_NEUTRAL`,
        are left out of the hash, so that every run key from before each existed still holds; one field predates
        that rule: `delay_train`, hashed since f967bd9, so a DP or flow run keyed before it has another key now)."""
        blob = json.dumps({"policy": self.policy, "config": key_dict(self.config_dict()), "val_fraction": val_fraction,
                           **({"task": task} if task != DEFAULT_TASK else {}),
                           **({"demos": self.demos} if self.demos is not None else {})}, sort_keys=True)
        return f"{self.policy}-{self.config}-s{self.seed}-{hashlib.sha256(blob.encode()).hexdigest()[:8]}"


def _where(i: int, run: dict[str, Any]) -> str:
    return f"[[run]] #{i + 1} ({run.get('policy', '?')})"


def _variants(i: int, run: dict[str, Any], policy: str) -> list[Variant]:
    entries = run.get("eval")
    if entries is None:
        return [Variant()]
    kinds = sampler_kinds(policy)
    if not kinds:
        raise BCBenchError(f"{_where(i, run)}: 'eval' variants (sampler/steps) apply to generative policies only "
                           "(diffusion, flow)")
    if not isinstance(entries, list) or not entries:
        raise BCBenchError(f"{_where(i, run)}: 'eval' must be a non-empty list of {{sampler, steps}} tables")
    out = []
    for e in entries:
        if not isinstance(e, dict) or set(e) - {"sampler", "steps", "spacing"} or "sampler" not in e:
            raise BCBenchError(f"{_where(i, run)}: each eval entry needs sampler (and steps, spacing), got {e}")
        if e["sampler"] not in kinds:
            raise BCBenchError(f"{_where(i, run)}: sampler must be {' or '.join(kinds)}, got '{e['sampler']}'")
        spacing = e.get("spacing", "trailing" if policy == "diffusion" else None)
        if policy == "diffusion" and spacing not in ("trailing", "leading"):
            raise BCBenchError(f"{_where(i, run)}: spacing must be trailing or leading, got '{spacing}'")
        if policy != "diffusion" and spacing is not None:
            raise BCBenchError(f"{_where(i, run)}: spacing applies to diffusion only")
        steps = e.get("steps", [100])
        steps = steps if isinstance(steps, list) else [steps]
        for k in steps:
            if not isinstance(k, int) or isinstance(k, bool) or not 1 <= k <= 100:
                raise BCBenchError(f"{_where(i, run)}: steps must be whole numbers in 1..100, got {k!r}")
            out.append(Variant(e["sampler"], k, spacing))
    return out


def _run_specs(i: int, run: Any) -> list[RunSpec]:
    if not isinstance(run, dict):
        raise BCBenchError(f"[[run]] #{i + 1} must be a table")
    if "minutes" in run:
        raise BCBenchError(f"{_where(i, run)}: 'minutes' is no longer a training budget: give 'steps' (optimiser "
                           "steps) or set optim.epochs; 'max_minutes' is a safety stop")
    unknown = sorted(set(run) - RUN_KEYS)
    if unknown:
        allowed = ", ".join(sorted(RUN_KEYS))
        raise BCBenchError(f"{_where(i, run)}: unknown key(s) {', '.join(unknown)} (allowed: {allowed})")
    policy = run.get("policy")
    if not isinstance(policy, str) or not policy:
        raise BCBenchError(f"{_where(i, run)}: policy must be a name, a plug-in or module:factory")
    if policy not in REGISTRY:
        return _outside_run_specs(i, run, policy)
    if "args" in run:
        raise BCBenchError(f"{_where(i, run)}: args go with an outside policy (module:factory or a plug-in); "
                           "a registered policy takes set = {...}")
    if "demos" in run and not is_learned(policy):
        raise BCBenchError(f"{_where(i, run)}: demos applies to a policy that trains, not the {policy} baseline")
    if "preset" in run and "config" in run:
        raise BCBenchError(f"{_where(i, run)}: give preset (or its old name, config), not both")
    config = run.get("preset", run.get("config", "quick"))  # the preset's name
    overrides = run.get("set", {})
    if not isinstance(overrides, dict):
        raise BCBenchError(f"{_where(i, run)}: 'set' must be a table of config overrides")
    if "steps" in run:
        steps = run["steps"]
        if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
            raise BCBenchError(f"{_where(i, run)}: steps must be a whole number >= 1, got {steps!r}")
        # `steps` is the budget: every epoch has >= 1 step, so epochs = steps never stops training first (the
        # preset's 60 epochs cut a 32,000-step arm of cpu-explore-dpflow to 20,520 steps); explicit epochs stay
        overrides = {"optim.epochs": steps, **overrides, "optim.max_steps": steps}
    try:
        make_config(policy, config, overrides)
    except BCBenchError as exc:
        raise BCBenchError(f"{_where(i, run)}: {exc}") from None
    minutes = run.get("max_minutes")
    if minutes is not None and (not isinstance(minutes, int | float) or minutes <= 0):
        raise BCBenchError(f"{_where(i, run)}: max_minutes must be a positive number, got {minutes!r}")
    seeds = _seeds(i, run)
    variants = _variants(i, run, policy)
    label = run.get("label", f"{policy} ({config})")
    every = run.get("eval_every")
    if every is not None and (not isinstance(every, int) or isinstance(every, bool) or every < 1):
        raise BCBenchError(f"{_where(i, run)}: eval_every must be a whole number of steps >= 1, got {every!r}")
    rt = run.get("realtime", False)
    if rt is True:
        realtime = variants[:1]
    elif rt is False:
        realtime = []
    elif isinstance(rt, list) and all(isinstance(k, str) for k in rt):
        by_key = {v.key: v for v in variants}
        missing = [k for k in rt if k not in by_key]
        if missing:
            raise BCBenchError(f"{_where(i, run)}: realtime names '{missing[0]}', which is not one of its eval "
                               f"variants ({', '.join(by_key)})")
        realtime = [by_key[k] for k in rt]
    else:
        raise BCBenchError(f"{_where(i, run)}: realtime must be true, false or a list of eval variant keys")
    doubles = run.get("doubles")
    if doubles is not None and not isinstance(doubles, str):
        raise BCBenchError(f"{_where(i, run)}: doubles names the label of the run this one checks (twice its steps)")
    n = run.get("check_episodes")
    if n is not None and (doubles is None or not isinstance(n, int) or isinstance(n, bool) or n < MIN_CHOICE_EPISODES):
        raise BCBenchError(f"{_where(i, run)}: check_episodes goes on a doubling run (doubles = ...) and must be a "
                           f"whole number >= {MIN_CHOICE_EPISODES}, got {n!r}")
    return [RunSpec(policy, config, s, minutes, overrides, variants, label, every, realtime, doubles=doubles,
                    check_episodes=n, demos=_demos(i, run)) for s in seeds]


def _demos(i: int, run: dict[str, Any]) -> int | None:
    n = run.get("demos")
    if n is not None and (not isinstance(n, int) or isinstance(n, bool) or n < 1):
        raise BCBenchError(f"{_where(i, run)}: demos must be a whole number of demonstrations >= 1, got {n!r}")
    return n


def _seeds(i: int, run: dict[str, Any]) -> list[int]:
    seeds = run.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
        raise BCBenchError(f"{_where(i, run)}: seeds must be a non-empty list of whole numbers >= 0")
    return seeds


def _outside_run_specs(i: int, run: dict[str, Any], policy: str) -> list[RunSpec]:
    """A policy from outside bcbench: it is resolved now (import, plug-in), built and checked when it runs."""
    try:
        load_factory(policy)
    except BCBenchError as exc:
        raise BCBenchError(f"{_where(i, run)}: {exc}") from None
    extra = sorted(set(run) & {"preset", "config", "steps", "max_minutes", "set", "eval", "eval_every", "demos"})
    if extra:
        raise BCBenchError(f"{_where(i, run)}: an outside policy is run as given: {', '.join(extra)} do not apply")
    args = run.get("args", {})
    if not isinstance(args, dict):
        raise BCBenchError(f"{_where(i, run)}: args must be a table of the factory's keyword arguments")
    seeds = _seeds(i, run)
    rt = run.get("realtime", False)
    if not isinstance(rt, bool):
        raise BCBenchError(f"{_where(i, run)}: realtime must be true or false for an outside policy")
    label = run.get("label", policy)
    return [RunSpec(policy, "-", s, None, {}, [Variant()], label, None, [Variant()] if rt else [], dict(args))
            for s in seeds]
