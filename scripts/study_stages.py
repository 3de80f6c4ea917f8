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
Never beside a running study on this machine: a timing needs the machine quiet, and two processes would both append
to the study's index.
"""

from __future__ import annotations

import sys
import time

from bcbench.study.runner import StudyRunner
from bcbench.study.spec import load_spec

KINDS = {"latency", "realtime", "eval", "check"}  # a training is the study's to run


def main(argv: list[str]) -> int:
    trained, again = "--trained" in argv, "--again" in argv
    argv = [a for a in argv if a not in ("--trained", "--again")]
    if len(argv) < 3:
        print("usage: study_stages.py [--trained] [--again] SPEC.toml OUT KIND [KIND ...]   (KIND: latency, "
              "realtime, eval, check)", file=sys.stderr)
        return 2
    spec_path, out, kinds = argv[0], argv[1], set(argv[2:])
    wrong = sorted(k for k in {*argv[:2], *kinds} if k.startswith("-")) or sorted(kinds - KINDS)
    if wrong:
        print(f"error: {', '.join(wrong)}: not a stage kind ({', '.join(sorted(KINDS))}) nor --trained / --again",
              file=sys.stderr)
        return 2
    if again and kinds != {"latency"}:  # an evaluation is run once (the test seeds' protocol); a sweep is hours
        print("error: --again times again; it runs latency stages only", file=sys.stderr)
        return 2
    runner = StudyRunner(load_spec(spec_path), out)
    todo = [s for s in runner.stages() if s[0] in kinds and (again or not runner.is_done(*s))]
    missing = [s for s in todo if s[1].learned and not runner.is_done("train", s[1], None)]
    if missing and trained:
        todo = [s for s in todo if s not in missing]
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
