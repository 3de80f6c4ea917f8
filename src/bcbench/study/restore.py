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

import json
import shutil
import sys
from datetime import UTC, datetime
from pathlib import Path

from bcbench.errors import BCBenchError
from bcbench.policies.publish import verify
from bcbench.protocol import DROPPED_RUNS, MIXING_REASON
from bcbench.utils.args import OneLineParser
from bcbench.utils.io import append_jsonl, atomic_path, read_json


def export_commit(export: Path) -> str:
    """The commit the study goes on at: the one every result file of the export was written at (the study's pin).

    A study whose pin moved while it ran (its folder says why, in MIXING_REASON, and the report prints it) goes on
    at its newest pin: the commit of the result file its last finished stage wrote (index.jsonl is in the order
    stages finished). Mixed commits without that account are refused: nobody said the code stayed the same."""
    commits = {c for f in sorted(export.glob("runs/*/*.json"))
               if isinstance(data := read_json(f), dict) and (c := data.get("git_commit"))}
    if len(commits) == 1:
        return commits.pop()
    if len(commits) > 1 and (export / MIXING_REASON).is_file():
        for line in reversed((export / "index.jsonl").read_text().splitlines()):
            f = export / json.loads(line).get("file", "")
            if f.is_file() and isinstance(data := read_json(f), dict) and data.get("git_commit") in commits:
                return data["git_commit"]
    raise BCBenchError(f"{export}: its result files carry {len(commits)} commits ({', '.join(sorted(commits))}) "
                       f"and no {MIXING_REASON} says why; a study goes on at one commit")


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
        record = read_json(meta)
        src = record.get("source") or {}
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
        attached.append(f"{src['run']}: {src['checkpoint']} ({record['weights']} weights) from {meta.parent}")
    return attached


def drop_unrunnable(spec_path: str | Path, out: str | Path) -> list[str]:
    """Drop every run whose training is done but whose weights are gone (trained on another machine, not
    published) while some of its evaluations or checks are still to run: they cannot run,
    and a retrained model, different on another CPU, must not have its scores mixed with the first one's. The run's
    folder and index lines go; the study trains it again from scratch; `dropped-runs.jsonl` says why, and the next
    export removes the first model's files (bcbench.analysis.export). Returns a line per dropped run."""
    from bcbench.study.runner import StudyRunner  # the stage list, exactly as the study runs it
    from bcbench.study.spec import load_spec

    out = Path(out)
    runner = StudyRunner(load_spec(spec_path), out, progress=False)
    pending: dict[Path, list[str]] = {}
    for stage, run, variant in runner.stages():
        d = runner.run_dir(run)
        # evaluations and checks only: every version of the runner has run those for a spec's variants (a stage
        # kind added later must not drop a run its pinned commit finished); timing and sweeps say so when reached
        if (run.learned and stage in ("eval", "check") and runner.is_done("train", run, None)
                and not (d / "checkpoints").exists() and not runner.is_done(stage, run, variant)):
            pending.setdefault(d, []).append(stage + (f"-{variant.key}" if variant else ""))
    lines = []
    for d, stages in pending.items():
        index = out / "index.jsonl"
        kept = [ln for ln in index.read_text().splitlines() if json.loads(ln).get("run") != d.name]
        with atomic_path(index) as tmp:
            tmp.write_text("".join(ln + "\n" for ln in kept))
        shutil.rmtree(d)
        why = (f"trained on another machine with {len(stages)} stage(s) still to run ({', '.join(stages[:3])}"
               f"{', ...' if len(stages) > 3 else ''}) and no published weights: trained again from scratch")
        when = datetime.now(UTC).isoformat(timespec="seconds")
        append_jsonl(out / DROPPED_RUNS, {"run": d.name, "why": why, "dropped": when})
        lines.append(f"{d.name}: {why}")
    return lines


def main(argv: list[str]) -> None:
    ap = OneLineParser(prog="python -m bcbench.study.restore", description=__doc__.split("\n")[0])
    ap.add_argument("dirs", nargs="*", metavar="DIR", help="EXPORT_DIR OUT_DIR [MODELS_DIR], or with --attach: "
                    "[MODELS_DIR] (default models)")
    ap.add_argument("--attach", metavar="OUT_DIR", help="attach published weights to this study folder only")
    ap.add_argument("--spec", help="the study file: drop restored runs that cannot go on (drop_unrunnable)")
    args = ap.parse_args(argv)
    if args.attach is not None and len(args.dirs) <= 1:
        out, models = args.attach, (args.dirs or ["models"])[0]
    elif args.attach is None and len(args.dirs) in (2, 3):
        out, models = args.dirs[1], (args.dirs[2:] or ["models"])[0]
        print(restore(args.dirs[0], out))
    else:
        ap.error("give EXPORT_DIR OUT_DIR [MODELS_DIR], or --attach OUT_DIR [MODELS_DIR]")
    for line in attach_published(out, models):  # stderr: stdout carries the commit only
        print(f"attached published weights to {line}", file=sys.stderr)
    for line in drop_unrunnable(args.spec, out) if args.spec else []:
        print(f"warning: dropped {line}", file=sys.stderr)


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except BCBenchError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
