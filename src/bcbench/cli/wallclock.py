"""The wall-clock commands: `bcbench serve` (a policy server) and `bcbench realtime --wall-clock` (the simulator in
real time against it, then the simulated-delay twin and the paired comparison). Wiring only: the server and the
real-time loop are bcbench.evaluation.serve and .wallclock, the comparison bcbench.analysis.wallclock."""

from __future__ import annotations

import argparse
import os
import select
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from bcbench.cli.policies import load_eval_policy
from bcbench.errors import BCBenchError
from bcbench.utils.io import write_json

SERVER_START_TIMEOUT_S = 600.0  # loading a model and (with --backend auto) timing its modes takes minutes at most
REALTIME_DEFAULTS = {"delays": [0, 1, 2, 4, 8], "execution": ["blocking", "async"], "strategy": ["naive"]}


def cmd_serve(args: argparse.Namespace) -> int:
    from bcbench.evaluation.serve import serve
    from bcbench.evaluation.wire import check_address

    bind = check_address(args.bind, args.allow_remote)  # before minutes of loading
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    args.episodes = 1  # load_eval_policy names a default folder with it; serve writes none
    policy, _ = load_eval_policy(args)
    _pusht_only(policy, "bcbench serve")
    info = {"pid": os.getpid(), "threads": _torch_threads(), "bind": bind}
    server = serve(policy, bind, info)
    print(f"bcbench serve: stopped after {server.served} answers and {server.refused} refusals", file=sys.stderr)
    return 0


def _torch_threads() -> int:
    import torch

    return torch.get_num_threads()


def _policy_flags(args: argparse.Namespace) -> list[str]:
    """The policy options of `realtime` as `serve` takes them, for the server this command starts."""
    out = []
    for flag in ("policy", "checkpoint", "sampler", "steps", "spacing", "seed", "backend", "precision", "device"):
        value = getattr(args, flag, None)
        if value is not None:
            out += [f"--{flag}", str(value)]
    for item in args.policy_arg or []:
        out += ["--policy-arg", item]
    if args.policy and args.preset:
        out += ["--preset", args.preset]
    return out + (["--reference"] if args.reference else [])


class SpawnedServer:
    """`bcbench serve` as a child process on a free loopback port; its stderr goes to LOG."""

    def __init__(self, args: argparse.Namespace, log: Path) -> None:
        from bcbench.evaluation.serve import LISTENING

        cmd = [sys.executable, "-m", "bcbench.cli", "serve", "--bind", "tcp://127.0.0.1:*", *_policy_flags(args)]
        # one core is the simulator's: torch's default (every core) spins its threads against it, and on a busy
        # 2-core machine made flow's Euler-10 call 12x slower (1.8 s against 0.15 s at one thread)
        self.threads = args.server_threads or max(1, (os.cpu_count() or 2) - 1)
        cmd += ["--threads", str(self.threads)]
        log.parent.mkdir(parents=True, exist_ok=True)
        self.log_path, self.log = log, open(log, "w")  # noqa: SIM115 (open for the child's lifetime)
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self.log, bufsize=0)
        deadline, self.address, seen = time.monotonic() + SERVER_START_TIMEOUT_S, None, b""
        while self.address is None:  # the endpoint it bound (a free port) is on the line it prints once bound
            if self.proc.poll() is not None or time.monotonic() > deadline:
                why = self.why() or f"no answer in {SERVER_START_TIMEOUT_S:g} s"
                self.stop()
                raise BCBenchError(f"the policy server did not start: {why}")
            if select.select([self.proc.stdout], [], [], 0.5)[0]:
                seen += os.read(self.proc.stdout.fileno(), 65536)
            for line in seen.decode(errors="replace").splitlines():
                if line.startswith(LISTENING):
                    self.address = line[len(LISTENING):].strip()

    def why(self) -> str | None:
        """None while the server runs; else its exit status and the last line it wrote on stderr."""
        if self.proc.poll() is None:
            return None
        self.log.flush()
        lines = [x for x in self.log_path.read_text().splitlines() if x.strip()]
        return f"exit status {self.proc.returncode}" + (f": {lines[-1]}" if lines else "")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()  # the server stops between requests on SIGTERM
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()


def _check_wallclock_args(args: argparse.Namespace) -> None:
    given = [f"--{k}" for k, v in REALTIME_DEFAULTS.items() if getattr(args, k) != v]
    given += [f for f, on in (("--profile", args.profile), ("--measured", args.measured), ("--resume", args.resume),
                              ("--bid-weak", args.bid_weak), ("--correction", getattr(args, "correction", None)))
              if on]
    if given:
        raise BCBenchError(f"--wall-clock runs async naive execution at the real delay: {', '.join(given)} "
                           "do not apply to it")
    if not args.server and not (args.checkpoint or args.policy):
        raise BCBenchError("--wall-clock needs the policy to serve (--checkpoint RUN_DIR or --policy NAME) or a "
                           "running server (--server ADDR)")
    if args.compare_with and args.no_compare:
        raise BCBenchError("--compare-with and --no-compare exclude each other")


def _pusht_only(policy: object, what: str) -> None:
    """The wire format (image 96x96x3, 2-D positions) and the wall-clock loop are Push-T's: one line otherwise."""
    from bcbench.tasks import task_of

    if task_of(policy).name != "pusht":
        raise BCBenchError(f"{what} serves Push-T policies only; this one was trained on {task_of(policy).name}")


def cmd_realtime_wallclock(args: argparse.Namespace) -> int:
    from bcbench.evaluation.wallclock import PolicyClient, WallClockConfig, run_wallclock
    from bcbench.evaluation.wire import check_address

    _check_wallclock_args(args)
    if (args.task or "pusht") != "pusht":
        raise BCBenchError("--wall-clock runs Push-T only (its wire format and simulator loop are Push-T's)")
    cfg = WallClockConfig(episodes=args.episodes, seed_start=args.seed_start, max_steps=args.max_steps or 300,
                          execution_horizon=args.execution_horizon, plan_delay=args.plan_delay)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(args.out) if args.out else Path(args.checkpoint or "runs") / f"wallclock-{stamp}"
    server = None
    if args.server:
        address, alive = check_address(args.server, args.allow_remote, "--server"), None
    else:
        server = SpawnedServer(args, out / "server.log")
        address, alive = server.address, server.why
        print(f"policy server started on {address} (pid {server.proc.pid}; its log: {out / 'server.log'})")
    client = PolicyClient(address, alive)
    try:
        record = run_wallclock(client, cfg, progress=not args.quiet)
    finally:
        client.close()
        if server is not None:
            server.stop()  # before the simulated twin runs: it needs the cores
    record["server"]["spawned"], record["server"]["address"] = server is not None, address
    write_json(out / "wallclock.json", record)
    _print_run(record, out)
    simulated = _simulated_twin(args, record, out)
    if simulated is not None:
        from bcbench.analysis.wallclock import comparison_lines, wallclock_comparison

        comparison = wallclock_comparison(record, simulated)
        write_json(out / "comparison.json", comparison)
        print("\n".join(comparison_lines(comparison)))
    print(f"  results: {out}")
    return 0


def _print_run(record: dict[str, Any], out: Path) -> None:
    s, dist = record["summary"], record["summary"]["delays"]
    seed = record["wallclock_config"]["seed_start"]
    print(f"{record['server']['name']}: {s['n']} wall-clock episodes from seed {seed}, mean score "
          f"{s['mean_score']:.3f}; re-plan thresholds {s['plan_delay']} ({s['plan_delay_from']})")
    if dist["calls"]:
        print(f"  {dist['calls']} calls: delay median {dist['median_steps']:g} steps ({dist['median_s'] * 1e3:.0f} ms),"
              f" p90 {dist['p90_steps']:g}, max {dist['max_steps']} ({dist['max_s'] * 1e3:.0f} ms); histogram "
              f"{dist['histogram']}; server compute median {s['compute_ms_median']:.1f} ms")
    busy = "" if s["busy_period_ms_max"] is None else (
        f"; while a call was out: median {s['busy_period_ms_median']:.1f} ms, max {s['busy_period_ms_max']:.1f} ms")
    print(f"  simulator step median {s['step_ms_median']:.1f} ms, max {s['step_ms_max']:.1f} ms{busy}")
    if s["overruns"]:
        by_step = s["overruns_by_step_time"]
        print(f"  overruns: {s['overruns']} of {s['steps']} steps ended after their period ({by_step} "
              f"by the simulator's own step time, the rest by a late start: the CPU busy elsewhere); the clock "
              f"slipped {s['slip_ms']:.0f} ms in all (recorded per episode)")
    if s["stale_chunks"]:
        print(f"  {s['stale_chunks']} answers arrived with all their actions in the past")
    print(f"  record: {out / 'wallclock.json'}")


def _simulated_twin(args: argparse.Namespace, record: dict[str, Any], out: Path) -> dict[str, Any] | None:
    """The simulated-delay record to compare with: --compare-with's, or run here (async at the rule's d), or None."""
    from bcbench.utils.io import read_json

    if args.compare_with:
        return read_json(args.compare_with)
    d = record["summary"]["simulated_delay"]
    if args.no_compare or d is None:
        return None
    if not (args.checkpoint or args.policy):
        print("  no simulated twin: give --checkpoint/--policy (the server's policy) or --compare-with FILE")
        return None
    from bcbench.evaluation.controller import async_actions_needed
    from bcbench.evaluation.evaluate import EvalConfig, evaluate
    from bcbench.protocol import CONTROL_DT_S

    meta = record["server"]
    if async_actions_needed(meta["chunk_start"], d, args.execution_horizon) > meta["pred_horizon"]:
        print(f"  no simulated twin: the calls' median delay, d = {d}, leaves no action of a {meta['pred_horizon']}-"
              "action chunk to execute in the simulated model (it cannot express this delay; the wall-clock run "
              "above is the only measure of it)")
        return None

    threads = (meta.get("server") or {}).get("threads")
    if threads:  # the server's thread count: its arithmetic, and no threads spinning against the simulators
        import torch

        torch.set_num_threads(int(threads))
    if args.checkpoint:  # the server's resolved mode, by its name (`--backend` takes a mode's name: modes.mode_name)
        vars(args).update(backend=record["policy"].get("mode") or "fast", precision="fp32", reference=False)
    policy, _ = load_eval_policy(args)  # in the server's resolved mode, so both ran the same computation
    cfg = EvalConfig(episodes=args.episodes, seed_start=args.seed_start, max_steps=args.max_steps, execution="async",
                     latency_ms=round(d * CONTROL_DT_S * 1e3, 6), execution_horizon=args.execution_horizon)
    print(f"simulated twin: async at d = {d} (the calls' median delay), same seeds")
    result = evaluate(policy, cfg, None, progress=not args.quiet, extra={"wallclock_twin": {"d": d}})
    write_json(out / f"simulated-async-d{d}.json", result)
    return result
