"""Why a task's best policy is under the goal: what the files say of the two causes issue 75 names.

A task whose best setting is under 80% must show why not: "its twice-the-steps check, the demonstration count". The
first is the confirm study's own check (the best setting's run trained again with twice its steps, paired on
validation episodes: `bcbench.analysis.convergence`). The second is an explore stage on validation seeds: the same
policy trained on more demonstrations and read on the episodes of the confirm run's check base
(`runs/*/check-*.json`: the run itself on 100 validation episodes), so the two pair episode by episode. across.json
names each task's stage folder:

    "more_demos": {"metaworld/pick-place": "../metaworld-explore-5-pick"}

Both readings are on validation episodes (200000+) and one training seed each: evidence on a cause, not a reported
score, and a difference says what that seed pair shows. Reads result files only.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bcbench.analysis.convergence import doubling_checks, run_verdicts, verdict_text
from bcbench.analysis.findings import DEFAULT_MARGIN
from bcbench.analysis.results import Row, load_check_rows, load_rows
from bcbench.analysis.studies import ACROSS_FILE, study_spec
from bcbench.errors import BCBenchError
from bcbench.stats import paired_bootstrap

NO_STEPS_CHECK = "no twice-the-steps check yet"
NO_DEMOS_STAGE = "no stage with more demonstrations yet"


def more_demos_folders(results: Path, spec: dict[str, Any], tasks: list[str]) -> dict[str, Path]:
    """across.json's `more_demos` (task -> explore folder), validated: each a task of the report, each folder a study
    on that task."""
    f = results / ACROSS_FILE
    named = spec.get("more_demos", {})
    if not isinstance(named, dict) or not all(isinstance(v, str) and v for v in named.values()):
        raise BCBenchError(f"{f}: 'more_demos' maps a task name to the folder of its explore stage with more "
                           "demonstrations (a path relative to it)")
    out = {}
    for task, rel in named.items():
        if task not in tasks:
            raise BCBenchError(f"{f}: 'more_demos' names {task}, which none of its 'tasks' folders is on")
        folder = results / rel
        if not (folder / "spec.json").is_file():
            raise BCBenchError(f"{f}: 'more_demos' names {rel}, which is not a study folder")
        on = study_spec(folder).get("task") or "pusht"
        if on != task:
            raise BCBenchError(f"{f}: 'more_demos' gives {rel} for {task}, but that study ran {on}")
        out[task] = folder
    return out


def steps_reading(task_folder: Path, best: Row) -> str:
    """The best setting's run's twice-the-steps verdicts (each checked training seed's, as its study's report reads
    them: `bcbench.analysis.convergence`), or that it has none yet."""
    margin = study_spec(task_folder).get("margin") or DEFAULT_MARGIN
    # a confirm study's checks are on validation episodes (check-*.json); an explore study's on its own episodes
    rows = load_check_rows(task_folder) or load_rows(task_folder, None, margin)
    verdicts = run_verdicts(doubling_checks(rows, margin), margin)
    mine = [v for (run, _), v in sorted(verdicts.items(), key=lambda kv: kv[0][1] or 0) if run == best.run_label]
    return "; ".join(verdict_text(v) for v in mine) if mine else f"twice the steps: {NO_STEPS_CHECK}"


def demos_readings(task_folder: Path, stage: Path) -> list[str]:
    """Each evaluation of the stage paired with the confirm run's check base of the same policy, sampler setting and
    training seed on a different demonstration count: both success rates on the shared validation episodes and the
    paired difference (more minus fewer)."""
    # the checked runs' own readings: a twice-the-steps run's check files share their policy, setting and seed
    bases = {(b.policy, b.variant, b.train_seed): b for b in load_check_rows(task_folder) if not b.doubles}
    out = []
    for r in sorted(load_rows(stage), key=lambda r: r.key):
        b = bases.get((r.policy, r.variant, r.train_seed))
        mine, theirs = r.data_split.get("demos"), b.data_split.get("demos") if b else None
        if b is None or mine is None or theirs is None or mine == theirs:
            continue
        est, lo, hi, n = paired_bootstrap(r.scores, [b.scores])
        if n == 0:
            out.append(f"{r.setting} from {mine} demonstrations shares no episode with the check base from {theirs}")
            continue
        shared = r.scores.keys() & b.scores.keys()
        more, fewer = (100 * sum(x.scores[k] for k in shared) / n for x in (r, b))
        name = b.label.split(", ")[0]  # "Diffusion Policy (cosine)": the label less its demos, horizons and size
        out.append(f"{name} {r.variant.upper()} (training seed {r.train_seed}) from {mine} demonstrations "
                   f"{more:.0f}% against {fewer:.0f}% from {theirs} on the same {n} validation episodes: "
                   f"{est:+.3f} [{lo:+.3f}, {hi:+.3f}] (paired; one training seed each; {stage.name})")
    return out


def why_not_lines(task_folder: Path, task: str, best: Row, stage: Path | None) -> str:
    """One line for a task under the goal: the twice-the-steps reading, then the demonstration-count one."""
    if stage is None:
        demos = f"demonstration count: {NO_DEMOS_STAGE}"
    else:
        found = demos_readings(task_folder, stage)
        demos = ("demonstration count: " + "; ".join(found) if found else
                 f"demonstration count: {stage.name} has no evaluation paired with this study's check bases yet")
    return f"- **{task}**: {steps_reading(task_folder, best)}; {demos}."
