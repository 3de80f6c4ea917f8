"""Why a task's best policy is under the goal: what the files say of the causes issue 75 names, and of one it allows.

A task whose best setting is under 80% must show why not: "its twice-the-steps check, the demonstration count". The
first is the confirm study's own check (the best setting's run trained again with twice its steps, paired on
validation episodes: `bcbench.analysis.convergence`). The others are explore stages on validation seeds: the same
policy, recipe and settings trained with one thing changed and read on the episodes of the confirm run's check base
(`runs/*/check-*.json`: the run itself on the study's `check_episodes` validation episodes), so the two pair episode
by episode. across.json names each task's stage folder, by what the stage changed:

    "more_demos": {"metaworld/pick-place": "../metaworld-explore-5-pick"},       # more demonstrations
    "larger_frame": {"metaworld/pick-place": "../metaworld-explore-6-pick128"}   # the task seen in larger frames

A larger-frame stage runs the task's `@SIZE` variant (the same seeds' demonstrations rendered larger) with the
frame's size and its crop overridden: those two overrides are the one difference it may have. Every reading is on
validation episodes (200000+) and one training seed each: evidence on a cause, not a reported score, and a difference
says what that seed pair shows. Reads result files only.
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


# what a stage changes: across.json's key -> (how a why line names it, what it says where a task has no such stage:
# only of the cause the issue names)
STAGE_KINDS = {"more_demos": ("demonstration count", NO_DEMOS_STAGE), "larger_frame": ("frame size", None)}
FRAME_KEYS = frozenset({"image_size", "crop"})  # a larger-frame stage's overrides: the frame and its crop


def _runs_on(kind: str, task: str, on: str) -> bool:
    """Whether a stage of `kind` for `task` may run `on`: the task itself, or for a larger frame its @SIZE variant."""
    base, _, size = on.partition("@")
    return on == task if kind == "more_demos" else base == task and size.isdigit()


def stage_folders(results: Path, spec: dict[str, Any], tasks: list[str]) -> dict[str, dict[str, Path]]:
    """across.json's `more_demos` and `larger_frame` (each task -> explore folder), validated: each a task of the
    report, each folder a study on that task (a larger-frame one on its `@SIZE` variant). Kind -> task -> folder."""
    f = results / ACROSS_FILE
    out: dict[str, dict[str, Path]] = {}
    for kind in STAGE_KINDS:
        named = spec.get(kind, {})
        if not isinstance(named, dict) or not all(isinstance(v, str) and v for v in named.values()):
            raise BCBenchError(f"{f}: '{kind}' maps a task name to the folder of its explore stage (a path relative "
                               "to it)")
        for task, rel in named.items():
            if task not in tasks:
                raise BCBenchError(f"{f}: '{kind}' names {task}, which none of its 'tasks' folders is on")
            folder = results / rel
            if not (folder / "spec.json").is_file():
                raise BCBenchError(f"{f}: '{kind}' names {rel}, which is not a study folder")
            on = study_spec(folder).get("task") or "pusht"
            if not _runs_on(kind, task, on):
                want = task if kind == "more_demos" else f"{task}@SIZE"
                raise BCBenchError(f"{f}: '{kind}' gives {rel} for {task}, but that study ran {on}, not {want}")
            out.setdefault(kind, {})[task] = folder
    return out


def steps_reading(task_folder: Path, checks: list[Row], best: Row) -> str:
    """The best setting's run's twice-the-steps verdicts (each checked training seed's, as its study's report reads
    them: `bcbench.analysis.convergence`), or that it has none yet; then the task's other checked runs' (a budget
    that suffices for one policy says nothing of another's). `checks`: the folder's check-*.json rows."""
    margin = study_spec(task_folder).get("margin") or DEFAULT_MARGIN
    # a confirm study's checks are on validation episodes (check-*.json); an explore study's on its own episodes
    rows = checks or load_rows(task_folder, None, margin)
    verdicts = sorted(run_verdicts(doubling_checks(rows, margin), margin).items(), key=lambda kv: (kv[0][0],
                                                                                                   kv[0][1] or 0))
    mine = [v for (run, _), v in verdicts if run == best.run_label]
    text = "; ".join(verdict_text(v) for v in mine) if mine else f"twice the steps: {NO_STEPS_CHECK}"
    others = [f"{_policy_name(run)} {v.est:+.3f} [{v.lo:+.3f}, {v.hi:+.3f}] ({v.verdict}, training seed "
              f"{v.train_seed})" for (run, _), v in verdicts if run != best.run_label]
    return text + (f"; the other policies' checks: {' and '.join(others)}" if others else "")


def _policy_name(label: str) -> str:
    """'Diffusion Policy (cosine)' of 'Diffusion Policy (cosine), 10 demos, horizons 4 / 3': the label less its demos,
    horizons and size."""
    return label.split(", ")[0]


def _check_bases(task_folder: Path, checks: list[Row]) -> dict[tuple[str, str, int | None], Row]:
    """The checked runs' own readings by (policy, setting, seed): a twice-the-steps run's check files share their
    policy, setting and seed and are left out; two checked runs under one key are ambiguous."""
    bases: dict[tuple[str, str, int | None], Row] = {}
    for b in checks:
        key = (b.policy, b.variant, b.train_seed)
        if b.doubles:
            continue
        if key in bases and bases[key].run_label != b.run_label:
            raise BCBenchError(f"{task_folder.name}: two checked runs of {b.policy} {b.variant} seed {b.train_seed} "
                               f"({bases[key].run_label}; {b.run_label}): which one an explore stage pairs with is "
                               "ambiguous")
        bases[key] = b
    return bases


def _one_difference(r: Row, b: Row, kind: str) -> tuple[str, str] | None:
    """How the stage's row and the base differ, as ('from 50 demonstrations', 'from 10') or ('at 128 px', 'at 96
    px'), where that is their one difference (same preset, recipe and data split but for the stage's change); None
    otherwise (then they do not pair)."""
    mine, theirs = r.data_split.get("demos"), b.data_split.get("demos")
    split = [{k: v for k, v in x.data_split.items() if k != "demos"} for x in (r, b)]  # which episodes it trains on
    if r.doubles or (r.preset, r.recipe) != (b.preset, b.recipe) or split[0] != split[1] or None in (mine, theirs):
        return None
    if kind == "more_demos":
        same = r.overrides == b.overrides and mine != theirs
        return (f"from {mine} demonstrations", f"from {theirs}") if same else None
    rest = [{k: v for k, v in x.overrides.items() if k not in FRAME_KEYS} for x in (r, b)]
    # the stage overrides the frame; the base saw the preset's (the stage's record holds the preset's value)
    big, small = r.overrides.get("image_size"), b.overrides.get("image_size", r.preset_values.get("image_size"))
    same = rest[0] == rest[1] and mine == theirs and None not in (big, small) and big > small
    return (f"at {big} px", f"at {small} px") if same else None


def stage_readings(task_folder: Path, checks: list[Row], stage: Path, kind: str) -> list[str]:
    """Each evaluation of the stage paired with the confirm run's check base of the same policy, sampler setting and
    training seed, trained with the same recipe and settings but for what the stage changed (`kind`: its
    demonstration count, or its frame size): both success rates on the shared validation episodes and the paired
    difference (stage minus base). A stage with no evaluation yet reads none; one whose evaluations pair with no base
    (they differ from it in more than the stage's change, or no base has their policy, setting and seed) says so."""
    bases = _check_bases(task_folder, checks)
    try:
        rows = load_rows(stage)
    except BCBenchError:  # nothing evaluated there yet
        return []
    out, based = [], 0  # `based`: the rows with a check base of their policy, setting and seed
    for r in sorted(rows, key=lambda r: r.key):
        b = bases.get((r.policy, r.variant, r.train_seed))
        based += b is not None
        if b is not None and (differs := _one_difference(r, b, kind)) is not None:
            out.append(_paired_line(r, b, stage.name, *differs))
    if rows and not out:
        many = len(rows) > 1
        out.append(f"{stage.name}'s {len(rows)} evaluation{'s' if many else ''} " + (
            f"pair{'' if many else 's'} with none of this study's check bases (the same policy, setting and training "
            f"seed, differing in its {STAGE_KINDS[kind][0]} alone)" if based else  # checks may come, or never run
            f"ha{'ve' if many else 's'} no check base in this study (a check of the same policy, setting and "
            "training seed)") + ": nothing to read")
    return out


def _paired_line(r: Row, b: Row, stage: str, mine: str, theirs: str) -> str:
    est, lo, hi, n = paired_bootstrap(r.scores, [b.scores])
    if n == 0:
        return f"{r.setting} {mine} shares no episode with the check base {theirs}"
    shared = r.scores.keys() & b.scores.keys()
    ours, base = (100 * sum(x.scores[k] for k in shared) / n for x in (r, b))
    name = _policy_name(b.label)
    setting = "" if r.variant == "default" else f" {r.variant.upper()}"
    return (f"{name}{setting} (training seed {r.train_seed}) {mine} {ours:.0f}% against {base:.0f}% {theirs} on the "
            f"same {n} validation episodes: {est:+.3f} [{lo:+.3f}, {hi:+.3f}] (paired; one training seed each; "
            f"{stage})")


def why_not_lines(task_folder: Path, task: str, best: Row, stages: dict[str, Path]) -> str:
    """One line for a task under the goal: the twice-the-steps reading, the demonstration-count one, then a
    larger frame's where a stage of it is named (`stages`: kind -> this task's folder)."""
    checks = load_check_rows(task_folder)  # read once: every reading uses the confirm run's check files
    parts = [steps_reading(task_folder, checks, best)]
    for kind, (what, none) in STAGE_KINDS.items():
        stage = stages.get(kind)
        if stage is None:
            parts += [f"{what}: {none}"] if none else []
            continue
        found = stage_readings(task_folder, checks, stage, kind)
        parts.append(f"{what}: " + ("; ".join(found) if found else
                                    f"{stage.name} has no evaluation yet"))
    return f"- **{task}**: {'; '.join(parts)}."
