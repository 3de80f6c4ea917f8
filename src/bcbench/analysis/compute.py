"""What a set of study folders cost, from their files: trainings, evaluations and timings, and the machines they ran on.

Issue 75's closing note asks for "the total compute and the machines". Every number here is a sum over records the
runs wrote themselves: a training's `train_time_s` (its optimiser steps, every session it ran in; evaluation during
training and pauses excluded: a floor on its wall time), an evaluation's `wall_time_s` (its episodes' rollouts, test
or validation) and the count of timing records. A run trained in pieces on several machines names each (its
`segments`); every one is listed, and its time is counted once, not split between them. Reads result files only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bcbench.analysis.results import cpu_text
from bcbench.analysis.studies import study_files
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


def _machines(record: dict[str, Any]) -> set[str]:
    """Each CPU a record names: its hardware, and for a training each session's segment."""
    named = [s for s in record.get("segments") or [] if isinstance(s, dict) and s.get("cpu_model")]
    hw = record.get("hardware")
    return {cpu_text(h) for h in [*named, *([hw] if isinstance(hw, dict) and hw.get("cpu_model") else [])]}


def folder_cost(folder: Path) -> Cost:
    """The compute every run under a study folder (or a combined report's studies) recorded."""
    c = Cost()
    for d, f in study_files(folder, "train_summary.json"):
        if "report" in f.relative_to(d).parts:
            continue
        d = read_json(f)
        c.trainings += 1
        c.train_s += float(d.get("train_time_s") or 0.0)
        c.machines |= _machines(d)
    for pattern in ("eval-*.json", "check-*.json"):
        for where, f in study_files(folder, pattern):
            d = read_json(f)
            if d.get("type") != "evaluation" or "report" in f.relative_to(where).parts:
                continue
            c.evaluations += 1
            c.episodes += len(d.get("episodes") or [])
            c.eval_s += float((d.get("summary") or {}).get("wall_time_s") or 0.0)
            c.machines |= _machines(d)
    for where, f in study_files(folder, "latency-*.json"):
        d = read_json(f)
        if d.get("type") == "latency" and "report" not in f.relative_to(where).parts:
            c.timings += 1
            c.machines |= _machines(d)
    return c


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
