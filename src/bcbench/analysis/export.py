"""A study's export: the result files a repository keeps (no checkpoints, no videos, no run still training), which
`bcbench report OUT --export results/NAME` copies and `bcbench.study.restore` goes on from on a new machine."""

from __future__ import annotations

import shutil
from pathlib import Path

from bcbench.analysis.studies import COMBINE_FILE
from bcbench.errors import BCBenchError
from bcbench.protocol import DROPPED_RUNS, training_done
from bcbench.utils.io import read_json, read_jsonl

EXPORTED = ("spec.json", "index.jsonl", "run.json", "train_summary.json", "normalizer.json", "metrics.jsonl",
            "segments.jsonl", "mixing-reason.txt", DROPPED_RUNS)


def unfinished_trainings(results: str | Path) -> list[Path]:
    """Run folders of a study whose training has not ended (run.json, but no train_summary.json of a finished
    training): what an export leaves out. Their files describe a training the export cannot carry on (its
    checkpoints are not exported), and a machine restoring the export would append a new training's curve and
    sessions to them."""
    out = []
    for run_json in sorted(Path(results).glob("runs/*/run.json")):
        summary = run_json.parent / "train_summary.json"
        if not summary.is_file() or not training_done(read_json(summary)):
            out.append(run_json.parent)
    return out


def export_results(results: str | Path, dest: str | Path) -> tuple[int, list[Path]]:
    """Copy a study's result files (no checkpoints, no videos, no run still training) to `dest`, after removing from
    `dest` the runs the study dropped (DROPPED_RUNS); returns the number of files and the run folders left out as
    unfinished."""
    results, dest = Path(results), Path(dest)
    if (results / COMBINE_FILE).exists():
        raise BCBenchError(f"{results} is a combined report ({COMBINE_FILE}): export each study it names instead")
    left_out = unfinished_trainings(results)
    if (results / DROPPED_RUNS).is_file():  # a model that is gone: its files leave the export (its run trains again)
        for rec in read_jsonl(results / DROPPED_RUNS):
            shutil.rmtree(dest / "runs" / rec["run"], ignore_errors=True)
    n = 0
    for f in sorted(results.rglob("*")):
        if "checkpoints" in f.parts or "report" in f.relative_to(results).parts or not f.is_file():
            continue
        if any(f.is_relative_to(d) for d in left_out):
            continue
        if f.name in EXPORTED or (f.suffix == ".json" and f.name.startswith(("eval", "check", "latency", "realtime"))):
            target = dest / f.relative_to(results)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, target)
            n += 1
    return n, left_out
