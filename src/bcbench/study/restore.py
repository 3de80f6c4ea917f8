"""Seed a study's run folder from its committed export, so that a machine without the folder goes on where the
export stopped instead of starting over.

Why: a study runs for longer than a session, and a new session may get a new machine whose ~/.cache is empty.
Every finished stage's result file is in the export (`bcbench report OUT --export results/NAME`), and the runner
skips a stage whose result file exists (bcbench.study.runner), so copying the export back is enough for stages
that read result files only. Checkpoints are not exported: a later stage that needs a restored run's weights (its
timing or real-time sweep) cannot run and says so when it reaches it.

    python -m bcbench.study.restore results/NAME OUT     copies, prints the one commit the export's files carry
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from bcbench.errors import BCBenchError
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


if __name__ == "__main__":
    try:
        if len(sys.argv) != 3:
            raise BCBenchError("usage: python -m bcbench.study.restore EXPORT_DIR OUT_DIR")
        print(restore(sys.argv[1], sys.argv[2]))
    except BCBenchError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
