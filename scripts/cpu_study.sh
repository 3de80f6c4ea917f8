#!/usr/bin/env bash
# Start or resume the converged CPU study (studies/cpu.toml) in the background at low priority, with its
# run folder outside the work tree so that a later session on this machine resumes it where it stopped.
#   scripts/cpu_study.sh          start / resume        scripts/cpu_study.sh stop     stop it (it saves)
#   scripts/cpu_study.sh status   progress               then: bcbench report ~/.cache/bcbench/cpu --export results/cpu
# Stop it before timing anything else on the machine: timings taken beside it mean nothing.
set -euo pipefail
cd "$(dirname "$0")/.."
export BCBENCH_HOME="${BCBENCH_HOME:-$HOME/.cache/bcbench}"
OUT="$BCBENCH_HOME/cpu"
LOG="$BCBENCH_HOME/cpu.log"
case "${1:-start}" in
  start)
    if pgrep -f "bcbench study studies/cpu.toml" >/dev/null; then echo "already running (log: $LOG)"; exit 0; fi
    make -s install
    mkdir -p "$BCBENCH_HOME"
    nohup nice -n 10 .venv/bin/bcbench study studies/cpu.toml --out "$OUT" >>"$LOG" 2>&1 &
    echo "started (pid $!): results in $OUT, log $LOG" ;;
  stop)
    pkill -INT -f "bcbench study studies/cpu.toml" && echo "asked to stop (it checkpoints and exits)" || echo "not running" ;;
  status)
    pgrep -f "bcbench study studies/cpu.toml" >/dev/null && echo "running" || echo "not running"
    [ -f "$OUT/index.jsonl" ] && echo "finished stages: $(wc -l < "$OUT/index.jsonl")"
    tail -c 400 "$LOG" 2>/dev/null | tr '\r' '\n' | grep -v '^$' | tail -1 ;;
  *) echo "usage: $0 [start|stop|status]" >&2; exit 2 ;;
esac
