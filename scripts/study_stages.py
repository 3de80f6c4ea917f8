"""Run only some kinds of a study's stages now, in the study's order, with the study's own (pinned) code.

Why: a study's driver runs timing and real-time stages last, after every training. When a new machine has to
retrain a long run (its checkpoints stayed on the old machine), the stages that need only published weights
(timing and real-time sweeps of training seed 0) can run first, alone on a quiet machine, and land in this
session. Each stage is computed and recorded exactly as the study records it (StudyRunner.compute / finish):
the same result file, the same index line; the study's later run skips them.

    cd ~/.cache/bcbench/src-<pin> && PYTHONPATH=src python /path/to/scripts/study_stages.py \
        SPEC.toml OUT latency realtime          (then start the study as usual; it goes on with the rest)

--trained runs those of the chosen stages whose training is done here and says how many wait for one (e.g. a
confirm study's seed-0 networks timed before its later trainings run); without it such a stage is an error before
anything runs. --again (latency only) times again the networks already timed, so that every network of a study is
timed in one sitting: a VM's speed drifts by tens of percent between sittings, and a task's latencies compare only
within one. The new timing replaces the file; the index gains a line (its seconds count in the study's time).
--any-seed (latency only) times, for a label whose timed seed (its lowest) has no trained network here, the same
label's network of the lowest training seed that has one, and records it in THAT run's folder (its own result file
and index line, as the study records a latency stage), e.g. a study restored on a new machine, where seed 0's
checkpoints stayed behind, times seed 1. Why that stands in: the time of an exact mode does not depend on the
weights, and the file says which weights ran (a latency record carries the policy's run_dir, checkpoint and
weights_sha256); a report reads a label's newest timing, whichever seed's it is (analysis.seeds), so that
--any-seed --again puts a whole task's networks in this sitting even where seed 0 was timed in an earlier one.
"Trained here" (for --trained too) means a finished training with a checkpoint in the run's folder: a restored
run's record of a finished training carries no weights. The study itself still times only a label's lowest seed, and
stops with an error at that stage while its network is not here.
Never beside a running study on this machine: a timing needs the machine quiet, and two processes would both append
to the study's index.
"""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING

from bcbench.study.runner import StudyRunner
from bcbench.study.spec import load_spec

if TYPE_CHECKING:  # names for annotations only: the study's pinned code is what runs
    from bcbench.study.spec_runs import RunSpec, Variant

    Stage = tuple[str, RunSpec, Variant | None]

KINDS = {"latency", "realtime", "eval", "check"}  # a training is the study's to run
FLAGS = ("--trained", "--again", "--any-seed")


def trained_here(runner: StudyRunner, run: RunSpec) -> bool:
    """A finished training whose network is here: a restored run has its summary but no checkpoint."""
    return runner.is_done("train", run, None) and (runner.run_dir(run) / "checkpoints").exists()


def stand_in(runner: StudyRunner, run: RunSpec) -> RunSpec | None:
    """The same label's shown run of the lowest training seed whose network is here (None: none is)."""
    seeds = [r for r in runner.spec.runs if r.label == run.label and r.learned and runner.spec.shown(r)]
    return next((r for r in sorted(seeds, key=lambda r: r.seed) if trained_here(runner, r)), None)


def stages_to_run(runner: StudyRunner, kinds: set[str], again: bool, any_seed: bool
                  ) -> tuple[list[Stage], list[Stage]]:
    """(the stages to run, those whose training is not here); with any_seed a latency stage of a run not trained
    here becomes the same stage of its stand-in (`stand_in`), printed, and is skipped where that is timed already."""
    todo = [s for s in runner.stages() if s[0] in kinds and (again or not runner.is_done(*s))]
    out: list[Stage] = []
    missing: list[Stage] = []
    for stage, run, variant in todo:
        if run.learned and not trained_here(runner, run) and any_seed and (other := stand_in(runner, run)):
            if not again and runner.is_done(stage, other, variant):
                continue
            print(f"{run.label} {variant.key}: s{other.seed} stands in for s{run.seed} (not trained here)", flush=True)
            run = other
        (missing if run.learned and not trained_here(runner, run) else out).append((stage, run, variant))
    return out, missing


def main(argv: list[str]) -> int:
    trained, again, any_seed = (f in argv for f in FLAGS)
    argv = [a for a in argv if a not in FLAGS]
    if len(argv) < 3:
        print("usage: study_stages.py [--trained] [--again] [--any-seed] SPEC.toml OUT KIND [KIND ...]   (KIND: "
              "latency, realtime, eval, check)", file=sys.stderr)
        return 2
    spec_path, out, kinds = argv[0], argv[1], set(argv[2:])
    wrong = sorted(k for k in {*argv[:2], *kinds} if k.startswith("-")) or sorted(kinds - KINDS)
    if wrong:
        print(f"error: {', '.join(wrong)}: not a stage kind ({', '.join(sorted(KINDS))}) nor "
              f"{' / '.join(FLAGS)}", file=sys.stderr)
        return 2
    flag = "--again" if again else "--any-seed" if any_seed else None
    if flag and kinds != {"latency"}:  # an evaluation is run once (the test seeds' protocol); a sweep is hours
        print(f"error: {flag} {'times again' if again else 'times another training seed'}; it runs latency "
              "stages only", file=sys.stderr)
        return 2
    runner = StudyRunner(load_spec(spec_path), out)
    todo, missing = stages_to_run(runner, kinds, again, any_seed)
    if missing and trained:
        print(f"{len(missing)} stage(s) wait for a training that is not done here: left for the study", flush=True)
    elif missing:
        print(f"error: {len(missing)} of these stages need a training that is not done here", file=sys.stderr)
        return 2
    for i, (stage, run, variant) in enumerate(todo, 1):
        print(f"[{i}/{len(todo)}] {stage} {run.label} s{run.seed} {variant.key if variant else ''}", flush=True)
        started = time.monotonic()
        runner.finish(stage, run, variant, runner.compute(stage, run, variant), time.monotonic() - started)
    print(f"{len(todo)} stage(s) run", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
