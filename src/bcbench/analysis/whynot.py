"""Why a task's best policy is under the goal: what the files say of the two causes issue 75 names.

A task whose best setting is under 80% must show why not: "its twice-the-steps check, the demonstration count". The
first is the confirm study's own check (the best setting's run trained again with twice its steps, paired on
validation episodes: `bcbench.analysis.convergence`). The second is an explore stage on validation seeds: the same
policy, recipe and settings trained on more demonstrations and read on the episodes of the confirm run's check base
(`runs/*/check-*.json`: the run itself on the study's `check_episodes` validation episodes), so the two pair episode
by episode. across.json names each task's stage folder:

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


def steps_reading(task_folder: Path, checks: list[Row], best: Row) -> str:
    """The best setting's run's twice-the-steps verdicts (each checked training seed's, as its study's report reads
    them: `bcbench.analysis.convergence`), or that it has none yet. `checks`: the folder's check-*.json rows."""
    margin = study_spec(task_folder).get("margin") or DEFAULT_MARGIN
    # a confirm study's checks are on validation episodes (check-*.json); an explore study's on its own episodes
    rows = checks or load_rows(task_folder, None, margin)
    verdicts = run_verdicts(doubling_checks(rows, margin), margin)
    mine = [v for (run, _), v in sorted(verdicts.items(), key=lambda kv: kv[0][1] or 0) if run == best.run_label]
    return "; ".join(verdict_text(v) for v in mine) if mine else f"twice the steps: {NO_STEPS_CHECK}"


def demos_readings(task_folder: Path, checks: list[Row], stage: Path) -> list[str]:
    """Each evaluation of the stage paired with the confirm run's check base of the same policy, sampler setting and
    training seed, trained with the same recipe and settings on a different demonstration count (so the count is the
    one difference): both success rates on the shared validation episodes and the paired difference (more minus
    fewer). A stage with no evaluation yet reads none."""
    bases: dict[tuple[str, str, int | None], Row] = {}
    # the checked runs' own readings: a twice-the-steps run's check files share their policy, setting and seed
    for b in checks:
        key = (b.policy, b.variant, b.train_seed)
        if b.doubles:
            continue
        if key in bases and bases[key].run_label != b.run_label:
            raise BCBenchError(f"{task_folder.name}: two checked runs of {b.policy} {b.variant} seed {b.train_seed} "
                               f"({bases[key].run_label}; {b.run_label}): which one a stage with more demonstrations "
                               "pairs with is ambiguous")
        bases[key] = b
    try:
        rows = load_rows(stage)
    except BCBenchError:  # nothing evaluated there yet
        return []
    out = []
    for r in sorted(rows, key=lambda r: r.key):
        b = bases.get((r.policy, r.variant, r.train_seed))
        if r.doubles or b is None or (r.recipe, r.overrides) != (b.recipe, b.overrides):
            continue
        mine, theirs = r.data_split.get("demos"), b.data_split.get("demos")
        if mine is None or theirs is None or mine == theirs:
            continue
        out.append(_paired_line(r, b, stage.name))
    return out


def _paired_line(r: Row, b: Row, stage: str) -> str:
    mine, theirs = r.data_split["demos"], b.data_split["demos"]
    est, lo, hi, n = paired_bootstrap(r.scores, [b.scores])
    if n == 0:
        return f"{r.setting} from {mine} demonstrations shares no episode with the check base from {theirs}"
    shared = r.scores.keys() & b.scores.keys()
    more, fewer = (100 * sum(x.scores[k] for k in shared) / n for x in (r, b))
    name = b.label.split(", ")[0]  # "Diffusion Policy (cosine)": the label less its demos, horizons and size
    setting = "" if r.variant == "default" else f" {r.variant.upper()}"
    return (f"{name}{setting} (training seed {r.train_seed}) from {mine} demonstrations {more:.0f}% against "
            f"{fewer:.0f}% from {theirs} on the same {n} validation episodes: {est:+.3f} [{lo:+.3f}, {hi:+.3f}] "
            f"(paired; one training seed each; {stage})")


def why_not_lines(task_folder: Path, task: str, best: Row, stage: Path | None) -> str:
    """One line for a task under the goal: the twice-the-steps reading, then the demonstration-count one."""
    checks = load_check_rows(task_folder)  # read once: both readings use the confirm run's check files
    if stage is None:
        demos = f"demonstration count: {NO_DEMOS_STAGE}"
    else:
        found = demos_readings(task_folder, checks, stage)
        demos = ("demonstration count: " + "; ".join(found) if found else
                 f"demonstration count: {stage.name} has no evaluation paired with this study's check bases yet")
    return f"- **{task}**: {steps_reading(task_folder, checks, best)}; {demos}."
