"""What a set of study folders cost, from their files: trainings, evaluations and timings, and the machines they ran on.

Issue 75's closing note asks for "the total compute and the machines". The hours and machines are each study's own
report's (`bcbench.analysis.results.study_time`, `study_machines`): a training's `train_time_s` (its optimiser steps,
every session it ran in; curve rollouts and pauses excluded: a floor on its wall time), an evaluation stage's recorded
seconds (test and validation), every CPU a record names (each session of a resumed training). A run trained on several
machines lists them all; its time is not split between them. The counts are of the files. Reads result files only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bcbench.analysis.results import study_machines, study_time
from bcbench.analysis.studies import run_files
from bcbench.utils.io import read_json


@dataclass
class Cost:
    """One folder's (or a total's) recorded compute."""

    trainings: int = 0
    train_s: float = 0.0
    evaluations: int = 0  # test and validation (twice-the-steps check bases) evaluations, each a file
    episodes: int = 0
    eval_s: float = 0.0
    timings: int = 0  # latency records (each a policy setting timed in its modes)
    machines: set[str] = field(default_factory=set)

    def add(self, other: Cost) -> None:
        self.trainings += other.trainings
        self.train_s += other.train_s
        self.evaluations += other.evaluations
        self.episodes += other.episodes
        self.eval_s += other.eval_s
        self.timings += other.timings
        self.machines |= other.machines


def _files(folder: Path, pattern: str) -> list[Path]:
    return [f for _, f in run_files(folder, pattern)]


def folder_cost(folder: Path) -> Cost:
    """The compute every run under a study folder (or a combined report's studies) recorded."""
    seconds = study_time(folder)
    evals = [read_json(f) for pattern in ("eval-*.json", "check-*.json") for f in _files(folder, pattern)]
    evals = [d for d in evals if d.get("type") == "evaluation"]
    timings = [f for f in _files(folder, "latency-*.json") if read_json(f).get("type") == "latency"]
    return Cost(trainings=len(_files(folder, "train_summary.json")), train_s=seconds["training"],
                evaluations=len(evals), episodes=sum(len(d.get("episodes") or []) for d in evals),
                eval_s=seconds["evaluation"], timings=len(timings), machines=set(study_machines(folder)))


def cost_table(named: list[tuple[str, Path]]) -> tuple[list[str], list[list[str]]]:
    """One row per (name, folder) and a total row: trainings and their hours, evaluations (episodes) and their hours,
    timing records, machines."""
    head = ["study", "trainings", "training (h)", "evaluations (episodes)", "evaluation (h)", "timings", "machines"]
    total, rows = Cost(), []
    for name, folder in named:
        c = folder_cost(folder)
        total.add(c)
        rows.append(_row(name, c))
    rows.append(_row("**total**", total))
    return head, rows


def _row(name: str, c: Cost) -> list[str]:
    return [name, str(c.trainings), f"{c.train_s / 3600:.2f}", f"{c.evaluations} ({c.episodes})",
            f"{c.eval_s / 3600:.2f}", str(c.timings), "; ".join(sorted(c.machines)) or "-"]
