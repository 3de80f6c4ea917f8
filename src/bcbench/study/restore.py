"""Seed a study's run folder from its committed export, so that a machine without the folder goes on where the
export stopped instead of starting over.

Why: a study runs for longer than a session, and a new session may get a new machine whose ~/.cache is empty.
Every finished stage's result file is in the export (`bcbench report OUT --export results/NAME`), and the runner
skips a stage whose result file exists (bcbench.study.runner), so copying the export back is enough for stages
that read result files only. Checkpoints are not exported, but the inference weights of a confirm study's training
seed 0 are published under models/ (bcbench.policies.publish): `attach_published` puts them back into the restored
run they came from (same run, same commit, sha256 checked), so that its later stages (timing, real-time sweeps)
run on any machine. A restored run with no published weights cannot run those stages and says so when it
reaches them.

    python -m bcbench.study.restore results/NAME OUT [MODELS]   copies, attaches MODELS/* (default models), prints
                                                                the one commit the export's files carry
    python -m bcbench.study.restore --attach OUT [MODELS]        attaches only, to a study folder that exists
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from bcbench.errors import BCBenchError
from bcbench.policies.publish import verify
from bcbench.utils.io import read_json


def export_commit(export: Path) -> str:
    """The one git commit every result file of the export was written at (the study's pin)."""
    commits = {c for f in sorted(export.glob("runs/*/*.json"))
               if isinstance(data := read_json(f), dict) and (c := data.get("git_commit"))}
    if len(commits) != 1:
        raise BCBenchError(f"{export}: its result files carry {len(commits)} commits ({', '.join(sorted(commits))}); "
                           "a study goes on at one commit")
    return commits.pop()


def restore(export: str | Path, out: str | Path) -> str:
    """Copy a study's export (no report) into `out`, which must not exist yet; returns the export's commit."""
    export, out = Path(export), Path(out)
    if not (export / "index.jsonl").exists() or not (export / "spec.json").exists():
        raise BCBenchError(f"{export} is not an exported study (no index.jsonl and spec.json)")
    if out.exists():
        raise BCBenchError(f"{out} exists: a study's own folder is never overwritten from an export")
    commit = export_commit(export)
    tmp = out.with_name(out.name + ".restoring")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(export, tmp, ignore=shutil.ignore_patterns("report"))
    tmp.rename(out)  # whole or not at all
    return commit


def attach_published(out: str | Path, models: str | Path) -> list[str]:
    """Copy each published model's checkpoint (models/NAME/checkpoints) into the study run it was published from,
    where that run is in `out` (the same run.json, so the same commit, config and data split) and has no checkpoint
    of its own; returns a line per attached model. The weights are the EMA the study evaluated, so its timing and
    real-time stages see the same model as its evaluations did."""
    out, models = Path(out), Path(models)
    attached = []
    for meta in sorted(models.glob("*/model.json")):
        src = read_json(meta).get("source") or {}
        run_dir = out / "runs" / str(src.get("run"))
        if not src.get("run") or not (run_dir / "run.json").is_file() or (run_dir / "checkpoints").exists():
            continue  # another study's model, or a run with checkpoints of its own (trained on this machine)
        run = read_json(run_dir / "run.json")
        if src.get("git_commit") != run.get("git_commit"):
            continue  # the same run name at another commit: not these weights
        if run != read_json(meta.parent / "run.json"):
            raise BCBenchError(f"{meta.parent} names run {src['run']} but its run.json differs from {run_dir}'s")
        verify(meta.parent)  # the weights file matches its recorded sha256
        tmp = run_dir / "checkpoints.attaching"
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.copytree(meta.parent / "checkpoints", tmp)
        tmp.rename(run_dir / "checkpoints")  # whole or not at all
        attached.append(f"{src['run']}: {src['checkpoint']} ({read_json(meta)['weights']} weights) from {meta.parent}")
    return attached


def main(argv: list[str]) -> None:
    if argv[:1] == ["--attach"] and len(argv) in (2, 3):
        out, models = argv[1], argv[2] if len(argv) == 3 else "models"
    elif len(argv) in (2, 3) and not argv[0].startswith("-"):
        out, models = argv[1], argv[2] if len(argv) == 3 else "models"
        print(restore(argv[0], out))
    else:
        raise BCBenchError("usage: python -m bcbench.study.restore EXPORT_DIR OUT_DIR [MODELS_DIR] | "
                           "--attach OUT_DIR [MODELS_DIR]")
    for line in attach_published(out, models):  # stderr: stdout carries the commit only
        print(f"attached published weights to {line}", file=sys.stderr)


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except BCBenchError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
