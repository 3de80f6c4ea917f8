"""`bcbench study SPEC --out DIR --status`: where a long study stands, read from its files only.

A study under Ray trains without progress bars (the workers have no terminal), and one that runs in the
background across sessions is looked at from another shell. This reads the folder the runner writes (result
files, each training's metrics.jsonl and run.json) and says, per stage kind, how many stages are done; per
training still going, its step, its recent rate and the time it has left at that rate; and for the trainings
not yet started, an estimate of their training time from the rates this study has measured for the same policy
and batch. It starts nothing and computes nothing heavy, so it is safe beside the study.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.study.runner import StudyRunner
from bcbench.study.spec import RunSpec, StudySpec
from bcbench.utils.io import read_json, read_jsonl

LAUNCH_FILE = "launch.json"  # how the running study was started: {"ray": false} or {"ray": true, "ray_cpus": N}
RATE_WINDOW = 20  # training log lines the recent rate is measured over (25 steps each by default)


@dataclass
class Training:
    """One training stage of the study, as its files show it."""

    run: RunSpec
    step: int = 0
    max_steps: int | None = None
    batch: int | None = None
    rate: float | None = None  # samples per second of training time over the last RATE_WINDOW log lines
    age_s: float | None = None  # seconds since its metrics were last written
    samples_per_epoch: float | None = None

    @property
    def samples_left(self) -> int | None:
        if self.max_steps is None or self.batch is None:
            return None
        return max(0, self.max_steps - self.step) * self.batch

    @property
    def seconds_left(self) -> float | None:
        left = self.samples_left
        return None if left is None or not self.rate else left / self.rate


def read_training(runner: StudyRunner, run: RunSpec) -> Training:
    """A training's step, size and recent rate from its run folder (nothing yet: step 0, no rate)."""
    d = runner.run_dir(run)
    optim = run.config_dict()["optim"]
    t = Training(run, max_steps=optim.get("max_steps"), batch=optim.get("batch_size"))
    if (d / "run.json").exists():  # the config the run was created with is the one it trains
        optim = read_json(d / "run.json")["config"]["optim"]
        t.max_steps, t.batch = optim.get("max_steps"), optim.get("batch_size")
    metrics = d / "metrics.jsonl"
    if not metrics.exists():
        return t
    lines = [r for r in read_jsonl(metrics) if "samples" in r and "train_time_s" in r]
    if lines:
        last = lines[-1]
        t.step, t.age_s = int(last["step"]), time.time() - metrics.stat().st_mtime
        if last.get("epoch"):
            t.samples_per_epoch = last["samples"] / last["epoch"]
        window = lines[-RATE_WINDOW:]
        dt = window[-1]["train_time_s"] - window[0]["train_time_s"]
        if dt > 0:
            t.rate = (window[-1]["samples"] - window[0]["samples"]) / dt
    return t


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def _lanes(runner: StudyRunner) -> int:
    """Trainings that run side by side: under Ray, its CPUs over one training's; in one process (no `resources`,
    or a study started without Ray, e.g. BCBENCH_RAY=0) one at a time. The study's launch.json says which; a
    folder without one (a study not started yet, or by an older bcbench) is assumed on Ray with every CPU."""
    cpus = runner.spec.resources.get("train", {}).get("cpus")
    f = runner.out / LAUNCH_FILE
    launch = read_json(f) if f.is_file() else {"ray": True, "ray_cpus": os.cpu_count() or 1}
    if not cpus or not launch.get("ray"):
        return 1
    return max(1, int(launch["ray_cpus"]) // cpus)


def status(runner: StudyRunner) -> dict[str, Any]:
    """Counts of stages done per kind, the trainings going and those waiting, and the estimates."""
    stages = [(s, r, runner.is_done(s, r, v)) for s, r, v in runner.stages()]  # each result file looked at once
    total, done = Counter(s for s, _, _ in stages), Counter(s for s, _, ok in stages if ok)
    trainings = [read_training(runner, run) for s, run, ok in stages if s == "train" and not ok]
    going = [t for t in trainings if t.step > 0]
    waiting = [t for t in trainings if t.step == 0]
    # The rate of a waiting run: the newest measured rate of a run of the same policy and batch in this study,
    # one still training before one finished (the machine and its load now, not a past session's).
    finished = [read_training(runner, run) for s, run, ok in stages if s == "train" and ok]
    rates = {(t.run.policy, t.batch): t.rate for t in [*finished, *going] if t.rate}
    per_epoch = next((t.samples_per_epoch for t in [*going, *finished] if t.samples_per_epoch), None)
    for t in waiting:
        t.rate = rates.get((t.run.policy, t.batch))
        if t.max_steps is None and per_epoch and t.batch:  # an epoch budget: steps from the data's size
            epochs = t.run.config_dict()["optim"].get("epochs")
            t.max_steps = int(epochs * per_epoch / t.batch) if epochs else None
    lanes = _lanes(runner)
    # List scheduling in the runner's order (the going ones first): each training to the lane that frees first.
    free, unknown = [0.0] * lanes, 0
    for t in [*going, *waiting]:
        if t.seconds_left is None:
            unknown += 1
            continue
        i = free.index(min(free))
        free[i] += t.seconds_left
    return {"total": total, "done": done, "going": going, "waiting": waiting, "lanes": lanes,
            "train_seconds_left": max(free) if len(trainings) > unknown else None, "unknown": unknown}


def format_status(runner: StudyRunner) -> str:
    s = status(runner)
    kinds = " ".join(f"{k} {s['done'][k]}/{n}" for k, n in s["total"].items())
    out = [f"{runner.spec.name}: {sum(s['done'].values())} of {sum(s['total'].values())} stages done ({kinds})"]
    for t in s["going"]:
        size = f"{t.step:,} / {t.max_steps:,} steps" if t.max_steps else f"step {t.step:,}"
        rate = f", {t.rate:.0f} samples/s lately" if t.rate else ""
        eta = f", about {_hours(t.seconds_left)} left at that rate" if t.seconds_left is not None else ""
        age = f" (written {_hours(t.age_s)} ago)" if t.age_s is not None else ""
        out.append(f"  training  {t.run.label} s{t.run.seed}: {size}{rate}{eta}{age}")
    for t in s["waiting"]:
        eta = f", about {_hours(t.seconds_left)} of training" if t.seconds_left is not None else ""
        out.append(f"  waiting   {t.run.label} s{t.run.seed}{eta}")
    if s["train_seconds_left"] is not None:
        unknown = f"; {s['unknown']} training(s) with no rate measured yet not counted" if s["unknown"] else ""
        lanes = "one at a time" if s["lanes"] == 1 else f"{s['lanes']} side by side"
        out.append(f"training left: about {_hours(s['train_seconds_left'])}, {lanes} "
                   f"(an estimate from this study's recent rates; evaluations, timing and real time come on top"
                   f"{unknown})")
    return "\n".join(out)




def study_status(spec: StudySpec, out: str | Path | None = None) -> str:
    """The status text of the study `spec` in `out` (default: where `bcbench study` writes it)."""
    out = Path(out) if out else Path("runs") / "studies" / spec.name
    if not (out / "spec.json").exists():
        raise BCBenchError(f"{out}: no study folder (no spec.json); name it with --out")
    return format_status(StudyRunner(spec, out, progress=False))
