"""Study specifications (TOML): which policies to train, with what budget, and how to evaluate them.

    [study]
    name = "quick"          # results go to runs/studies/NAME unless --out says otherwise
    task = "pusht"          # the task every run trains and is evaluated on (`bcbench data tasks`; default pusht)
    episodes = 40           # evaluation episodes per variant (the study's 40)
    seed_start = 100000     # Diffusion Policy's test seeds
    val_fraction = 0.1      # the study's 90/10 split
    latency = true          # time each variant at batch 1
    threads = 2             # torch threads for training and timing
    device = "cpu"          # where training, evaluation and timing run: cpu, cuda or auto
    margin = 0.05           # equivalence margin of the findings' verdicts (mean score)
    backend = "torch"       # evaluation: torch (default, its fast exact form) or openvino
    precision = "fp32"      # with openvino: fp32 (exact), bf16 or int8 (approximate)
    latency_modes = ["reference", "fast"]   # timed forms (bcbench.evaluation.backends.MODES)
    resources = { train = { cpus = 2, gpus = 1 }, eval = { cpus = 1 } }   # per stage kind, under --ray
    purpose = "explore"     # explore: validation seeds 200000+ only, >= 50 episodes (choices are made here);
                            # confirm: fixed presets on the test seeds 100000+ (bcbench.protocol)
    check_episodes = 100    # confirm: validation episodes of the twice-the-steps checks (>= 50)
    realtime = { delays = [1, 2, 4], execution = ["async"], profiles = ["a100"], measured = true,
                 strategies = ["naive", "rtc"], execution_horizon = 8, rtc_jacobian = false }
                            # strategies: naive, rtc, bid, ensemble, or prefix (every swept run trained with
                            # delay_train; bcbench.policies.prefix)
                            # the real-time sweep of the runs that ask for one (run key `realtime`): defaults
                            # [1, 2, 4, 8], both executions, no profile, measured, naive, s = 8 - d, the paper's RTC

    [[run]]
    policy = "diffusion"
    preset = "quick"        # diffusion also has quick_linear / paper_linear (`config` is the old name of this key)
    steps = 3000            # training budget in optimiser steps (optional; default: the preset's epochs); the
                            # preset's epochs do not cut it short (they are lifted unless `set` gives them)
    max_minutes = 60        # safety stop (optional): a run that hits it is marked "schedule not finished"
    eval_every = 500        # learning curve: rollouts every 500 steps on validation seeds (optional)
    seeds = [0]             # one training run per seed
    set = { "optim.epochs" = 8 }                    # config overrides (optional)
    eval = [{ sampler = "ddpm", steps = [10, 100] }, { sampler = "ddim", steps = [10], spacing = "leading" }]
                            # spacing: trailing (default; every K starts from pure noise) or leading
    doubles = "LABEL"       # this run checks the convergence of run LABEL: twice its steps, same preset. In a
                            # confirm study the two (same seed) are compared on validation episodes only
                            # (check-*.json); the doubling run is not evaluated on the test seeds
    check_episodes = 400    # a doubling run only: its check on this many validation episodes (default: the
                            # study's); a changed count re-runs the check of both runs, not the rest
    demos = 10              # train on the first 10 episodes of the training split (optional; default all): the
                            # demonstration-count axis; validation split unchanged; the count is in the run key

Validation happens before anything runs and names the offending entry in one line.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.modes import MODES, mode_name
from bcbench.policies import REGISTRY, make_config
from bcbench.policies.baselines import task_refusal
from bcbench.protocol import MIN_CHOICE_EPISODES, check_purpose, test_informed_entries
from bcbench.study.spec_runs import RUN_KEYS as RUN_KEYS  # RUN_KEYS, Variant re-exported: [[run]] tables are read there
from bcbench.study.spec_runs import RunSpec, _run_specs
from bcbench.study.spec_runs import Variant as Variant
from bcbench.study.spec_tables import realtime_table, resources_table
from bcbench.tasks import DEFAULT_TASK, get_task

STUDY_KEYS = {"name", "episodes", "seed_start", "val_fraction", "latency", "threads", "max_steps", "rate_hz",
              "latency_min_calls", "latency_min_seconds", "device", "margin", "curve_episodes", "realtime",
              "check_episodes", "backend", "precision", "latency_modes", "resources", "purpose",
              "test_informed", "task"}


@dataclass
class StudySpec:
    name: str
    task: str = DEFAULT_TASK  # every run of a study trains and is scored on one task (pusht, metaworld/NAME)
    episodes: int = 40
    seed_start: int = 100_000
    val_fraction: float = 0.1
    latency: bool = True
    threads: int | None = None
    max_steps: int = 300
    rate_hz: float = 10.0
    latency_min_calls: int = 100
    latency_min_seconds: float = 2.0
    device: str = "cpu"  # where training, evaluation and timing run: cpu, cuda or auto
    margin: float = 0.05  # equivalence margin (mean score) of the findings' verdicts
    curve_episodes: int = 20  # episodes per learning-curve rollout (validation seeds 200000+)
    realtime: dict[str, Any] | None = None  # the real-time sweep: delays, execution, profiles, measured
    backend: str = "torch"  # evaluation backend (bcbench.evaluation.backends)
    precision: str = "fp32"
    latency_modes: tuple[str, ...] = ("reference", "fast")  # forms the latency stage times
    resources: dict[str, dict[str, float]] = field(default_factory=dict)  # stage kind -> cpus, gpus (Ray)
    runs: list[RunSpec] = field(default_factory=list)
    source: str = ""
    purpose: str | None = None  # explore or confirm (bcbench.protocol); None: written before the seed protocol
    # a confirm study's twice-the-steps check: the doubling run and the seed it checks are compared on this many
    # validation episodes (seeds 200000+; the test seeds are not for choices); >= 50
    check_episodes: int = 100
    # decisions behind this study that a test-seed result informed (bcbench.protocol.test_informed_entries): the
    # protocol's exceptions, stated in the study's own file and carried into every report that reads it
    test_informed: list[dict[str, str]] = field(default_factory=list)

    def checks_on_validation(self, run: RunSpec) -> bool:
        """In a confirm study: a doubling run, or the run of the same label and seed that one checks."""
        return self.purpose == "confirm" and (run.doubles is not None or any(
            d.doubles == run.label and d.seed == run.seed for d in self.runs))

    def check_size(self, run: RunSpec) -> int:
        """Validation episodes of the run's twice-the-steps check: the doubling run's own count where it gives one
        (both runs of a check are compared on the same episodes), else the study's."""
        double = run if run.doubles is not None else next(
            (d for d in self.runs if d.doubles == run.label and d.seed == run.seed), None)
        return (double.check_episodes if double else None) or self.check_episodes

    def shown(self, run: RunSpec) -> bool:
        """Whether the run is evaluated (and timed) as a setting: a confirm study's doubling runs are only checks."""
        return not (self.purpose == "confirm" and run.doubles is not None)


def parse_spec(data: dict[str, Any], source: str = "") -> StudySpec:
    study = data.get("study", {})
    if not isinstance(study, dict):
        raise BCBenchError("[study] must be a table")
    extra = sorted(set(data) - {"study", "run"}) + [f"study.{k}" for k in sorted(set(study) - STUDY_KEYS)]
    if extra:
        raise BCBenchError(f"unknown key(s) in the spec: {', '.join(extra)}")
    runs = data.get("run")
    if not isinstance(runs, list) or not runs:
        raise BCBenchError("the spec lists no runs: add at least one [[run]] table")
    spec = StudySpec(name=str(study.get("name", Path(source).stem or "study")), source=source)
    if "task" in study:
        if not isinstance(study["task"], str):
            raise BCBenchError(f"study.task must be a task's name, got {study['task']!r}")
        spec.task = get_task(study["task"]).name  # an unknown name: one line naming the choices
        # the task's cap and control rate (what latency verdicts read) unless study.max_steps / rate_hz say otherwise
        spec.max_steps, spec.rate_hz = get_task(spec.task).max_steps, get_task(spec.task).control_hz
    for key, typ, ok in (("episodes", int, lambda v: v >= 1), ("seed_start", int, lambda v: v >= 0),
                         ("val_fraction", float, lambda v: 0 < v < 1), ("latency", bool, lambda v: True),
                         ("threads", int, lambda v: v >= 1), ("max_steps", int, lambda v: 1 <= v <= 10_000),
                         ("rate_hz", float, lambda v: v > 0), ("latency_min_calls", int, lambda v: v >= 1),
                         ("latency_min_seconds", float, lambda v: v >= 0),
                         ("device", str, lambda v: v in ("cpu", "cuda", "auto")),
                         ("margin", float, lambda v: 0 < v < 1), ("curve_episodes", int, lambda v: v >= 1),
                         ("check_episodes", int, lambda v: v >= MIN_CHOICE_EPISODES)):
        if key in study:
            v = study[key]
            good = isinstance(v, typ) or (typ is float and isinstance(v, int) and not isinstance(v, bool))
            if not good or (typ is int and isinstance(v, bool)) or not ok(v):
                raise BCBenchError(f"study.{key} has an invalid value {v!r}")
            setattr(spec, key, v)
    spec.purpose = study.get("purpose")
    problem = check_purpose(spec.purpose, spec.seed_start, spec.episodes)
    if problem:
        raise BCBenchError(f"study.purpose: {problem}")
    if "realtime" in study:
        spec.realtime = realtime_table(study["realtime"])
    _backend_keys(study, spec)
    spec.resources = resources_table(study.get("resources", {}))
    spec.test_informed = test_informed_entries(study.get("test_informed", []), "study.test_informed")
    for i, run in enumerate(runs):
        spec.runs.extend(_run_specs(i, run))
    _check_doubling(spec)
    _check_strategies(spec)
    for r in spec.runs:  # a baseline that cannot act in the task: refused now, not after hours of training
        only = getattr(REGISTRY[r.policy][1], "only_task", None) if not r.outside else None
        if why := task_refusal(r.policy, only, spec.task):
            raise BCBenchError(f"{r.label}: {why}")
    return spec


def _check_strategies(spec: StudySpec) -> None:
    """Every strategy a study sweeps runs on every run it sweeps: prefix on delay-conditioned runs only; a correction
    head belongs to one base run, so a study does not sweep it."""
    kinds = (spec.realtime or {}).get("strategies", [])
    if "correction" in kinds:
        raise BCBenchError("study.realtime.strategies: a correction head is trained on one base run; sweep it with "
                           "bcbench realtime --checkpoint BASE --strategy correction --correction HEAD_RUN")
    for r in spec.runs if "prefix" in kinds else []:
        if r.realtime and not (r.learned and getattr(make_config(r.policy, r.config, r.overrides), "delay_train",
                                                     (0, 0))[1] > 0):
            raise BCBenchError(f"study.realtime.strategies has prefix, but run {r.label} is not trained with delay "
                               "conditioning (set = { delay_train = [LO, HI] }, flow or diffusion)")


def _check_doubling(spec: StudySpec) -> None:
    """A convergence check (`doubles = "LABEL"`) trains the same policy and preset as the run it checks, with twice
    its optimiser steps (stated as `steps` in both, or as optim.epochs in both)."""
    by_label = {r.label: r for r in spec.runs if r.learned}
    for r in spec.runs:
        if r.doubles is None:
            continue
        base = by_label.get(r.doubles)
        if base is None or base.policy != r.policy or base.config != r.config:
            raise BCBenchError(f"run '{r.label}' doubles '{r.doubles}', which is not a run of the same policy and "
                               "preset in this study")
        for key in ("optim.max_steps", "optim.epochs"):
            if key in r.overrides and key in base.overrides:
                if r.overrides[key] != 2 * base.overrides[key]:
                    raise BCBenchError(f"run '{r.label}' must have twice the {key} of '{r.doubles}' "
                                       f"({2 * base.overrides[key]}), got {r.overrides[key]}")
                break
        else:
            raise BCBenchError(f"run '{r.label}' and '{r.doubles}' must both state steps (or optim.epochs) so that the "
                               "doubling can be checked")
        if r.variants != base.variants:
            raise BCBenchError(f"run '{r.label}' must evaluate the same variants as '{r.doubles}'")
        if r.demos != base.demos:  # a check on other data would test the data, not the budget
            raise BCBenchError(f"run '{r.label}' must train on the same demos as '{r.doubles}' ({base.demos}), "
                               f"got {r.demos}")
        every = [x.overrides.get("optim.val_every") for x in (base, r)]
        if every[0] != every[1]:  # a plateau schedule reads the cadence: the check would mix it into the budget
            raise BCBenchError(f"run '{r.label}' must validate at the cadence of '{r.doubles}' (optim.val_every "
                               f"{every[0]}), got {every[1]}")


def _backend_keys(study: dict[str, Any], spec: StudySpec) -> None:
    spec.backend, spec.precision = str(study.get("backend", "torch")), str(study.get("precision", "fp32"))
    try:
        mode_name(spec.backend, spec.precision)
    except BCBenchError as e:
        raise BCBenchError(f"study.backend/precision: {e}") from None
    modes = study.get("latency_modes", list(spec.latency_modes))
    if not isinstance(modes, list) or not modes or any(m not in MODES for m in modes):
        raise BCBenchError(f"study.latency_modes must be a non-empty list of {', '.join(MODES)}, got {modes!r}")
    spec.latency_modes = tuple(modes)


def load_spec(path: str | Path, task: str | None = None) -> StudySpec:
    """The study file at `path`; `task` (`bcbench study --task`) in place of its study.task (with that task's episode
    cap unless study.max_steps sets one)."""
    path = Path(path)
    if not path.is_file():
        raise BCBenchError(f"study spec {path} not found")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise BCBenchError(f"{path} is not valid TOML: {exc}") from None
    if task is not None:
        data.setdefault("study", {})
        if isinstance(data["study"], dict):
            data["study"]["task"] = task
    return parse_spec(data, str(path))
