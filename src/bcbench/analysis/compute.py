"""What a set of study folders cost, from their files: trainings, evaluations and timings, and the machines they ran on.

Issue 75's closing note asks for "the total compute and the machines". The hours and machines are each study's own
report's (`bcbench.analysis.results.study_time`, `study_machines`): a training's `train_time_s` (its optimiser steps,
every session it ran in; curve rollouts and pauses excluded: a floor on its wall time), an evaluation stage's recorded
seconds (test and validation), every CPU a record names (each session of a resumed training). A run trained on several
machines lists them all; its time is not split between them. The counts are of the files. When a folder's timings ran
(`timing_sittings`) is read from its index: a latency compares with another of the same sitting, not across sittings
on a machine whose speed drifts. Reads result files only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

from bcbench.analysis.results import index_lines, study_machines, study_time
from bcbench.analysis.studies import run_files
from bcbench.utils.io import read_json

SITTING_GAP_S = 1800  # timings with no timing between them for this long belong to two sittings


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


def timing_sittings(folder: Path) -> list[tuple[datetime, datetime]]:
    """(start, end) of each sitting in which a study folder's (or a combined report's studies') latency stages ran,
    from their index lines (`results.index_lines`: a stage's end and its seconds), in time order: stages less than
    SITTING_GAP_S apart share a sitting. Why: a timing compares with another from the same few minutes; a VM's speed
    drifts between sittings."""
    last: dict[tuple[Path, str], dict] = {}  # a stage run again: its last line is the timing its file holds
    for d, i in index_lines(folder):
        if i.get("stage") == "latency" and i.get("finished"):
            last[(d, str(i.get("file")))] = i
    spans = []
    for i in last.values():
        end = datetime.fromisoformat(i["finished"])
        end = end.replace(tzinfo=UTC) if end.tzinfo is None else end.astimezone(UTC)  # the study writes UTC
        spans.append((end - timedelta(seconds=float(i.get("seconds") or 0.0)), end))
    out: list[tuple[datetime, datetime]] = []
    for start, end in sorted(spans):
        if out and (start - out[-1][1]).total_seconds() < SITTING_GAP_S:
            out[-1] = (out[-1][0], max(out[-1][1], end))
        else:
            out.append((start, end))
    return out


def sittings_text(named: list[tuple[str, Path]]) -> str:
    """One sentence: when each named folder's latencies were timed (UTC), sitting by sitting; '' where none was."""
    def span(s: tuple[datetime, datetime]) -> str:
        a, b = s  # UTC (timing_sittings)
        return f"{a:%Y-%m-%d %H:%M}-{b:%H:%M}" if a.date() == b.date() else f"{a:%Y-%m-%d %H:%M}-{b:%Y-%m-%d %H:%M}"

    parts = []
    for name, folder in named:
        sittings = timing_sittings(folder)
        if sittings:
            many = f"{len(sittings)} sittings, " if len(sittings) > 1 else ""
            parts.append(f"{name} {many}{', '.join(span(s) for s in sittings)}")
    if not parts:
        return ""
    return ("Timed (UTC; a sitting ends where no timing ran for "
            f"{SITTING_GAP_S // 60} min): {'; '.join(parts)}. A latency compares with one of the same sitting: a "
            "machine's speed drifts between sittings.")
