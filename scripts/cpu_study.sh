#!/usr/bin/env bash
# Start or resume a long study (default: the converged CPU study, studies/cpu.toml) in the background at low
# priority, with its run folder outside the work tree so that a later session on this machine resumes it
# where it stopped. SPEC names another study file; its folder, log and pin are named after it.
#   scripts/cpu_study.sh [start] [SPEC]   start / resume     scripts/cpu_study.sh stop [SPEC]   stop it (it saves)
#   scripts/cpu_study.sh status [SPEC]    progress (stages done; each training's step, rate, time left)
#   then: bcbench report ~/.cache/bcbench/cpu --export results/cpu
# The study runs at ONE commit from start to end: the first start pins the current (clean) HEAD and runs
# from its own clone of it ($BCBENCH_HOME/src-<commit>), so the work tree can move on while it runs for
# hours and every result it writes carries the same commit. Starting afresh at a newer commit means
# deleting $BCBENCH_HOME/cpu and $BCBENCH_HOME/cpu.commit. On a machine without the folder (a new session's machine
# starts with an empty cache) a study with a committed export results/NAME goes on from it, at its commit
# (bcbench.study.restore); the stages that need a restored run's weights (timing, real time) run where those weights
# are published under models/ (seed 0 of a confirm study), and cannot elsewhere.
# Stop it before timing anything else on the machine: timings taken beside it mean nothing.
# nice 10 yields to other work of the same login session only: with the kernel's autogroup scheduling
# (/proc/sys/kernel/sched_autogroup_enabled = 1 on this project's VMs) a job started in another session (nohup,
# setsid) gets an equal share whatever its nice. To give foreground work the machine, pause the study:
#   scripts/cpu_study.sh pause [SPEC]   ...   scripts/cpu_study.sh resume [SPEC]   (SIGSTOP / SIGCONT of its processes
#   and all their children)
# A spec with a `resources` table (e.g. resources = { train = { cpus = 1 }, eval = { cpus = 1 } }) runs its stages as
# Ray tasks on this machine's cores, side by side where the table allows (`bcbench study --ray`): independent
# trainings with 1 thread each train more samples/s in all than one at a time with every thread
# (results/train-throughput/threads/). Timing stages still run alone. BCBENCH_RAY=0 runs such a spec in one process
# instead, one stage at a time with `threads`: fewer samples/s in all, but the first of two long trainings finishes in
# about half the time, which is what counts when a session's machine may not come back. BCBENCH_RAY_CPUS=N gives a
# spec's Ray instance N CPUs instead of all: two studies side by side each with one core (each starts its own local
# Ray instance; they coexist), e.g. a small-policy study on the core another study's last training leaves free.
# A timing stage then has its own instance to itself, not the machine: let the other study finish before one starts
# (`pause` stops every study's Ray workers, ray::..., not only SPEC's).
set -euo pipefail
cd "$(dirname "$0")/.."
export BCBENCH_HOME="${BCBENCH_HOME:-$HOME/.cache/bcbench}"
SPEC="${2:-studies/cpu.toml}"
[ -f "$SPEC" ] || { echo "error: no study file $SPEC" >&2; exit 2; }
NAME="$(basename "$SPEC" .toml)"
OUT="$BCBENCH_HOME/$NAME"
LOG="$BCBENCH_HOME/$NAME.log"
PIN="$BCBENCH_HOME/$NAME.commit"
PATTERN="bcbench.cli study .*$SPEC"
case "${1:-start}" in
  start)
    if pgrep -f "$PATTERN" >/dev/null; then echo "already running (log: $LOG)"; exit 0; fi
    make -s install
    mkdir -p "$BCBENCH_HOME"
    # A MetaWorld study trains on generated demonstrations, which a new machine's empty cache lacks: generate each
    # task's store again from its committed record (results/metaworld-demos) and check it byte for byte (minutes).
    TASKS="$(grep -oE 'task = "metaworld/[^"]+"' "$SPEC" | cut -d'"' -f2 | sort -u || true)"
    if [ -n "$TASKS" ]; then
      # shellcheck disable=SC2086  # one word a task
      MUJOCO_GL="${MUJOCO_GL:-egl}" .venv/bin/python scripts/demo_records.py --ensure results/metaworld-demos $TASKS
    fi
    # A new machine (empty cache) goes on from the committed export, at the commit its files were written at.
    if [ ! -d "$OUT" ] && [ -f "results/$NAME/index.jsonl" ]; then
      .venv/bin/python -m bcbench.study.restore "results/$NAME" "$OUT" > "$PIN.tmp" && mv "$PIN.tmp" "$PIN"
      echo "restored $OUT from results/$NAME (its finished stages are skipped), pinned at $(cut -c1-12 "$PIN")"
    fi
    if [ ! -f "$PIN" ]; then
      if [ -n "$(git status --porcelain --untracked-files=no)" ]; then
        echo "error: the work tree has uncommitted changes; commit them first (the study pins a commit)" >&2; exit 2
      fi
      git rev-parse HEAD > "$PIN"
    fi
    COMMIT="$(cat "$PIN")"
    # The study runs the spec as it was at the pin. A spec extended since (seeds or settings added at a later
    # commit) would otherwise run nothing new and say "done" (a restore pins the export's commit, which predates
    # the extension): say so, and how to move the pin.
    if ! git show "$COMMIT:$SPEC" 2>/dev/null | cmp -s - "$SPEC"; then
      echo "warning: $SPEC differs between the pinned commit ${COMMIT:0:12} and the work tree; the study runs the" \
           "pinned one. To run the work tree's, write its commit into $PIN (results/$NAME then needs a" \
           "mixing-reason.txt saying why the code is the same)" >&2
    fi
    SRC="$BCBENCH_HOME/src-${COMMIT:0:12}"
    if [ ! -d "$SRC/.git" ]; then
      git clone --quiet --no-checkout "$PWD" "$SRC.tmp" && git -C "$SRC.tmp" checkout --quiet "$COMMIT"
      mv "$SRC.tmp" "$SRC"
    fi
    # A restored run whose inference weights are published (models/NAME, training seed 0) gets them back, so its
    # timing and real-time stages can run here too; a restored run with stages still to run and no weights (trained
    # on another machine) is dropped and trained again, never mixed with a new model's scores (idempotent).
    if [ -d "$OUT/runs" ]; then .venv/bin/python -m bcbench.study.restore --attach "$OUT" models --spec "$SRC/$SPEC"; fi
    # The clone has no ../shared beside it: name the data explicitly. PYTHONPATH puts the pinned code
    # ahead of the work tree's editable install; the work tree's .venv supplies the libraries.
    export BCBENCH_DATA="${BCBENCH_DATA:-$PWD/../shared/data/pusht/pusht_cchi_v7_replay.zarr}"
    # exec: no shell stays behind holding the caller's stdout open (a tool that waits for EOF would hang).
    RAY=()
    if [ "${BCBENCH_RAY:-1}" != 0 ] && grep -Eq '^[[:space:]]*resources[[:space:]]*=' "$SRC/$SPEC"; then
      RAY=(--ray --ray-cpus "${BCBENCH_RAY_CPUS:-$(nproc)}")
    fi
    (cd "$SRC" && PYTHONPATH="$SRC/src" exec nohup nice -n 10 "$OLDPWD/.venv/bin/python" -m bcbench.cli \
        study "$SPEC" --out "$OUT" "${RAY[@]}" >>"$LOG" 2>&1 </dev/null &)
    echo "started at commit ${COMMIT:0:12}: results in $OUT, log $LOG" ;;
  stop)
    pkill -INT -f "$PATTERN" && echo "asked to stop (it checkpoints and exits)" || echo "not running" ;;
  pause|resume)  # the driver and, under Ray, its workers (ray::...): nothing of the study computes while paused
    SIG=$([ "$1" = pause ] && echo STOP || echo CONT)
    pgrep -f "$PATTERN" >/dev/null || { echo "not running"; exit 0; }
    # with every descendant: an evaluation's episode workers (multiprocessing) are children of the driver or of
    # a Ray worker, and would go on computing beside a timing if only their parent stopped
    tree() { local p; for p in "$@"; do echo "$p"; tree $(pgrep -P "$p"); done; }
    PIDS="$(tree $(pgrep -f "$PATTERN") $(pgrep -f "^ray::"))"
    kill -"$SIG" $PIDS 2>/dev/null || true
    echo "${1}d ($(echo $PIDS | wc -w) processes)" ;;
  status)
    pgrep -f "$PATTERN" >/dev/null && echo "running" || echo "not running"
    [ -f "$PIN" ] && echo "pinned commit: $(cut -c1-12 "$PIN")"
    [ -f "$OUT/index.jsonl" ] && echo "finished stages: $(wc -l < "$OUT/index.jsonl")"
    tail -c 400 "$LOG" 2>/dev/null | tr '\r' '\n' | grep -v '^$' | tail -1
    # each training's step, rate and time left (Ray workers show no progress bar), read from the study's files
    # read with the pinned code when its clone is here: a run's key can change between commits (a config field added
    # since), and the work tree's code would count the pinned runs as not started
    SRC="$BCBENCH_HOME/src-$(cut -c1-12 "$PIN" 2>/dev/null)"
    [ -f "$PIN" ] && [ -d "$SRC/.git" ] || SRC="$PWD"
    if [ -f "$OUT/spec.json" ]; then
      (cd "$SRC" && PYTHONPATH="$SRC/src" "$OLDPWD/.venv/bin/python" -m bcbench.cli study "$SPEC" --out "$OUT" \
        --status) || true
    fi ;;
  *) echo "usage: $0 [start|stop|status|pause|resume] [SPEC]" >&2; exit 2 ;;
esac
