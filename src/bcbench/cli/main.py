"""The `bcbench` command line. Every failure the user can cause ends in one line on stderr, exit 2.

Each command imports the stages it runs inside its handler, the one place in bcbench where imports are local:
it buys start-up time (`bcbench --help`, `bcbench data info` and `bcbench report` never load torch, OpenVINO or
matplotlib). Module level holds only the torch-free core.
"""

from __future__ import annotations

import argparse
import os
import sys
from functools import partial
from pathlib import Path
from typing import Any

from bcbench.cli import data, wallclock
from bcbench.cli.choose import cmd_choose  # noqa: F401  (a handler, found by name in main)
from bcbench.cli.parser import build_parser
from bcbench.cli.policies import (
    load_eval_policy,
    load_head,
    load_weak,
    measured_sources,
    sampler_of,
    strategy_config,
)
from bcbench.errors import BCBenchError
from bcbench.protocol import strategy_label
from bcbench.stats import fmt_estimate, fmt_share
from bcbench.utils.args import EXIT_USAGE
from bcbench.utils.io import read_json, write_json
from bcbench.utils.system import git_commit

EXIT_INTERRUPTED = 130


# ----------------------------------------------------------------------------- commands


def cmd_eval(args: argparse.Namespace) -> int:
    from bcbench.evaluation.evaluate import EvalConfig, evaluate
    from bcbench.tasks import task_of

    strategy = strategy_config(args, args.strategy)
    policy, default_out = load_eval_policy(args)
    cfg = EvalConfig(episodes=args.episodes, seed_start=args.seed_start, max_steps=args.max_steps,
                     task=args.task or task_of(policy).name, action_horizon=args.action_horizon,
                     workers=args.workers, video=args.video, execution=args.execution, latency=args.latency,
                     latency_ms=args.latency_ms, execution_horizon=args.execution_horizon, strategy=strategy)
    out = Path(args.out) if args.out else default_out
    result = evaluate(policy, cfg, out, progress=not args.quiet, weak=load_weak(args, policy), head=load_head(args),
                      record=args.record)
    s = result["summary"]
    print(f"{policy.name}: {s['n']} episodes from seed {cfg.seed_start}{ran_text(policy)}")
    n = s["n"]  # shares with Wilson intervals (a bootstrap gives [0, 0] at 0%)
    print(f"  mean score {fmt_estimate(s['mean_score'])}   > 0.5 {fmt_share(s['share_above_0.5'], n)}"
          f"   > 0.9 {fmt_share(s['share_above_0.9'], n)}   success {fmt_share(s['success_rate'], n)}")
    print(f"  wall {s['wall_time_s']:.1f} s, {s['env_steps']} env steps ({s['env_steps_per_s']:.0f}/s on "
          f"{s['workers']} workers), {s['policy_calls']} batched policy calls ({s['policy_time_s']:.2f} s)")
    print(f"  results: {out / 'eval.json'}" + (f"; rollouts: {args.record}" if args.record else ""))
    videos = [e["video"] for e in result["episodes"] if e["video"]]
    if videos:
        print(f"  videos: {', '.join(videos)}")
    return 0


def ran_text(policy: Any) -> str:
    """", sampler ddim, 10 steps (trailing), mode fast": what a trained policy ran, named on the console."""
    info = getattr(policy, "info", None)
    if info is None:
        return ""
    sampler = (f", sampler {info.sampler}, {info.steps} steps" + (f" ({info.spacing} spacing)" if info.spacing else "")
               if info.sampler else "")
    return f"{sampler}, mode {info.mode or 'fast'}"


def _parse_sets(items: list[str] | None) -> dict[str, Any]:
    """--set key=value pairs; values are JSON when they parse as JSON (numbers, lists, true), else strings."""
    from bcbench.policies.outside import parse_kwargs

    out = parse_kwargs(items, "--set")
    return out


def cmd_train(args: argparse.Namespace) -> int:
    from bcbench.training.loop import TrainOptions, discard_new_run, new_run, train
    from bcbench.training.parts import Distributed
    from bcbench.utils.device import pick_device

    dist = Distributed(pick_device(args.device))  # under torchrun: join the process group (else world 1)

    opts = TrainOptions(max_minutes=args.max_minutes, threads=args.threads, device=args.device, data=args.data,
                        eval_every=args.eval_every, eval_episodes=args.eval_episodes, progress=not args.quiet,
                        demos=args.demos)
    if args.resume:
        run_dir = Path(args.resume)
        if args.precision or args.set or args.pretrained or args.demos:
            raise BCBenchError("--precision, --set, --pretrained and --demos define a new run; a resumed run keeps "
                               "its config")
    else:
        if not args.policy:
            raise BCBenchError("choose --policy NAME (or --resume RUN_DIR)")
        overrides = _parse_sets(args.set)
        if args.pretrained:
            from bcbench.policies import make_config

            if not hasattr(make_config(args.policy, args.preset), "pretrained"):
                raise BCBenchError(f"--pretrained applies to policies with an ImageNet-style ResNet to initialise "
                                   f"(resnet50), not to '{args.policy}'")
            overrides["pretrained"] = args.pretrained
        if args.seed is not None:
            overrides["seed"] = args.seed
        if args.precision:
            overrides["optim.precision"] = args.precision
        if dist.world > 1 and not args.out:
            raise BCBenchError("under torchrun, name the run folder with --out (every process trains into it)")
        run_dir = (new_run(args.policy, args.preset, overrides, args.out, opts, args.task) if dist.main
                   else Path(args.out))
    if dist.world > 1:
        import torch

        torch.distributed.barrier()  # the run folder exists before any process reads it
    if not dist.main:
        train(run_dir, opts)
        return 0
    print(f"run directory: {run_dir}")
    try:
        s = train(run_dir, opts)
    except BCBenchError:
        if not args.resume:  # a failed start (e.g. data that does not load) leaves no run folder behind
            discard_new_run(run_dir)
        raise
    sps = f"{s['samples_per_s']:.0f}" if s["samples_per_s"] else "-"
    print(f"{s['policy']} ({s['preset']}): stopped ({s['stopped']}) at step {s['step']}/{s['total_steps']} "
          f"= {s['epochs']:.2f} epochs; {sps} samples/s on {s['device']} ({s['threads']} threads, {s['precision']})")
    print(f"  validation loss {s['val_loss']:.5f} (best {s['best_val_loss']:.5f}); parameters {s['parameters']:,}")
    if s["policy"] == "correction":  # a head runs beside its base (bcbench.policies.correction)
        base = read_json(Path(run_dir) / "run.json")["config"]["base"]
        print(f"  sweep: bcbench realtime --checkpoint {base} --strategy naive correction --correction {run_dir}")
    else:
        print(f"  evaluate: bcbench eval --checkpoint {run_dir} --episodes 40")
    return 0


def cmd_params(args: argparse.Namespace) -> int:
    from bcbench.policies import learned_policies, make_policy
    from bcbench.policies.config import config_to_dict
    from bcbench.policies.encoders import count_parameters, resnet18, resnet50
    from bcbench.reference import STUDY_PARAMETERS, sized_label
    from bcbench.tasks import get_task

    task = get_task(args.task)
    print(f"task {task.name}: {task.state_dim} state values and a {task.image_size}x{task.image_size} frame in, "
          f"{task.action_dim} action values out (the study's counts are Push-T's)")
    print(f"{'policy':<18}{'paper':>14}{'study':>14}{'diff':>9}{'quick':>12}{'cpu':>12}  "
          "cpu preset, as reports name it")
    for name in learned_policies():
        paper, quick, cpu = (make_policy(name, p, task) for p in ("paper", "quick", "cpu"))
        n, study = paper.num_parameters(), STUDY_PARAMETERS.get(name)
        diff = f"{100 * (n - study) / study:+.3f}%" if study else "-"
        named = sized_label(name, name, cpu.num_parameters(), config_to_dict(cpu.config))  # the study's size or not
        print(f"{name:<18}{n:>14,}{(f'{study:,}' if study else '-'):>14}{diff:>9}{quick.num_parameters():>12,}"
              f"{cpu.num_parameters():>12,}  {named}")
        for part, count in getattr(paper, "parameter_breakdown", lambda: {})().items():
            print(f"  {part:<16}{count:>14,}")
    print("backbones (no fc head):")
    for label, net in (("resnet18 (batch)", resnet18("batch")), ("resnet18 (group)", resnet18("group")),
                       ("resnet50 (batch)", resnet50("batch"))):
        print(f"  {label:<16}{count_parameters(net):>14,}")
    return 0


def cmd_study(args: argparse.Namespace) -> int:
    from bcbench.study import run_study
    from bcbench.study.spec import load_spec

    spec = load_spec(args.spec, args.task)
    if args.check:
        print(f"{args.spec}: valid; {len(spec.runs)} run(s): " + ", ".join(f"{r.label} s{r.seed}" for r in spec.runs))
        return 0
    if args.status:
        from bcbench.study.progress import study_status

        print(study_status(spec, args.out))
        return 0
    summary = run_study(spec, args.out, args.data, progress=not args.quiet, ray=args.ray, ray_cpus=args.ray_cpus)
    print(f"study {spec.name}: {summary['executed']} stage(s) run, {summary['skipped']} already done, "
          f"{summary['seconds'] / 60:.1f} min; results in {summary['out']}")
    if not args.no_report:
        from bcbench.analysis.report import write_report

        paths = write_report(summary["out"])
        print(f"report: {paths['markdown']}  and  {paths['html']}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from bcbench.analysis.across import is_across
    from bcbench.analysis.export import export_results
    from bcbench.analysis.report import write_report

    if is_across(args.results) and (args.export or args.include):  # it reads other folders' files, has none
        raise BCBenchError("a report across tasks (across.json) has no result files of its own: export or "
                           "--include each task's folder")
    if args.export:
        n, left_out = export_results(args.results, args.export)
        print(f"exported {n} result files to {args.export}"
              + (f"; left out {len(left_out)} run(s) still training: {', '.join(d.name for d in left_out)}"
                 if left_out else ""))
    paths = write_report(args.results, extra_dirs=args.include or [])
    for warning in paths["warnings"]:
        print(warning, file=sys.stderr)
    print(f"report: {paths['markdown']}  and  {paths['html']}")
    return 0


def cmd_realtime(args: argparse.Namespace) -> int:
    from bcbench.analysis.figures import figure5_realtime, realtime_figure
    from bcbench.analysis.findings import DEFAULT_MARGIN
    from bcbench.analysis.realtime import margin_power_sentence, safe_delay_sentence
    from bcbench.evaluation.realtime import finished_settings, realtime_record, sweep
    from bcbench.policies.learned import PolicyRunner

    args.no_ema = False
    if args.wall_clock:
        return wallclock.cmd_realtime_wallclock(args)
    strategies = sorted(dict.fromkeys(args.strategy), key=lambda k: k != "naive")  # naive first: the others' bar
    configs = [strategy_config(args, k, several=True) for k in strategies]  # options checked before any episode
    if args.correction and "correction" not in strategies:
        raise BCBenchError("--correction goes with --strategy correction")
    policy, default_out = load_eval_policy(args)
    weak = load_weak(args, policy) if "bid" in strategies else None
    head = load_head(args) if "correction" in strategies else None
    from bcbench.evaluation.strategies import Strategy

    # each strategy can run on this policy: checked before hours of episodes
    built = {k: Strategy(c, policy, weak if k == "bid" else None, head if k == "correction" else None)
             for k, c in zip(strategies, configs, strict=True)}
    trained = tuple(getattr(getattr(getattr(policy, "model", None), "config", None), "delay_train", (0, 0)))
    longer = [d for d in args.delays if d > trained[1]] if "prefix" in strategies and "async" in args.execution else []
    if longer:  # a clean prefix longer than any the network saw in training: refused, not extrapolated silently
        raise BCBenchError(f"--strategy prefix: this model was trained with delays {trained[0]}-{trained[1]} "
                           f"(delay_train); --delays {' '.join(map(str, longer))} would give it a longer clean prefix")
    # several strategies timed together, before any episode (latency_sources says why)
    measured = measured_sources(policy, built) if args.measured and len(strategies) > 1 else {}
    out = Path(args.out) if args.out else default_out.with_name(default_out.name.replace("eval-", "realtime-"))
    mode = policy.info.mode if isinstance(policy, PolicyRunner) else None  # what apply_mode set; baselines: none
    base = args.label or (f"{policy.name} ({mode})" if mode else policy.name)
    ran = sampler_of(args) if args.checkpoint else (args.sampler, args.steps, args.spacing)
    variant = dict(zip(("sampler", "steps", "spacing"), ran, strict=True))  # what ran (a model's recorded setting)
    plain = None  # naive's sweep, once run
    for kind, strategy in zip(strategies, configs, strict=True):
        # naive alone writes to --out itself (as before strategies); several: one folder each
        where = out if strategies == ["naive"] else out / kind
        done = finished_settings(where, policy, args.episodes, args.seed_start, args.max_steps,
                                 args.execution_horizon, strategy, args.task) if args.resume else None
        if done:
            print(f"{kind}: resuming, {len(done)} settings kept from {where}: {', '.join(done)}")
        results = sweep(policy, args.delays, args.execution, args.episodes, args.profile or [], args.measured,
                        progress=not args.quiet, max_steps=args.max_steps, seed_start=args.seed_start, task=args.task,
                        execution_horizon=args.execution_horizon, strategy=strategy,
                        weak=weak if kind == "bid" else None, measured_source=measured.get(kind),
                        head=head if kind == "correction" else None,
                        on_setting=partial(_write_newest, where), done=done)  # each setting's file as it finishes
        print(f"{policy.name}, strategy {kind}: score under real-time execution ({args.episodes} episodes each)")
        for name, r in results.items():
            s = r["summary"]
            d = ", ".join(f"d={k}: {v}" for k, v in s["delay_steps"].items()) or "d=0"
            print(f"  {name:<28} {fmt_estimate(s['mean_score'])}   ({d} calls)")
        realtime_figure({policy.name: results}, where / "realtime.png")
        if figure5_realtime({policy.name: results}, where / "fig5_realtime.png") is None:
            (where / "fig5_realtime.png").unlink(missing_ok=True)  # no measured setting this time: no stale figure
        print(f"  {safe_delay_sentence(results, DEFAULT_MARGIN, plain)}")  # naive runs first: plain is None for it
        plain = results if kind == "naive" else plain
        if power := margin_power_sentence({policy.name: results}, DEFAULT_MARGIN):
            print(f"  {power}")
        # One record of the whole sweep, the form a study's report reads: inside a study's folder (e.g. beside a
        # run's own sweep, with another --backend), `bcbench report` shows it under its label.
        write_json(where / "realtime-sweep.json", realtime_record(
            results, "bcbench realtime", strategy_label(base, kind),
            {**variant, "strategy": kind, **strategy.variant_extra()}, DEFAULT_MARGIN, args.device))
    if len(strategies) > 1:
        from bcbench.analysis.strategies import load_strategy_sweeps, strategy_figure, strategy_table

        sweeps = load_strategy_sweeps(out)
        strategy_figure(sweeps, out / "strategies.png")
        print("\n".join(strategy_table(sweeps, DEFAULT_MARGIN)))
    print(f"  results and plots: {out}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from bcbench.evaluation.backends import apply_mode
    from bcbench.policies.checkpoint import load_runner

    runner = load_runner(args.run_dir, use_ema=not args.no_ema)
    apply_mode(runner, f"{args.format}-{args.precision}")  # exports (or finds the cached export), compiles once
    print(f"{runner.name}: {args.format} {args.precision} graphs ({', '.join(runner.model.graphs)}) in "
          f"{runner.model.deployment['export']}")
    return 0


def _write_newest(folder: Path, done: dict[str, dict[str, Any]]) -> None:
    """A sweep's newest finished setting, written as it finishes: a sweep stopped at its fifth setting keeps four."""
    name, result = next(reversed(done.items()))
    write_json(folder / f"{name}.json", result)


def cmd_publish(args: argparse.Namespace) -> int:
    from bcbench.policies.publish import publish

    rec = publish(args.run_dir, args.out, args.scores, force=args.force)
    print(f"{rec['name']}: {rec['policy']} ({rec['parameters']:,} parameters, {rec['weights']} weights, "
          f"{rec['file']['bytes'] / 1e6:.1f} MB fp32) from {rec['source']['run']} {rec['source']['checkpoint']}; "
          f"reproduces {rec['scores']['file']} (mean {rec['scores']['mean_score']:.3f} over "
          f"{rec['scores']['episodes']} episodes)")
    print(f"  run it: bcbench eval --checkpoint {args.out} --episodes 3 --seed-start {rec['scores']['seed_start']}")
    return 0


def cmd_tiers(args: argparse.Namespace) -> int:
    from bcbench.evaluation.tiers import run_tiers, tiers_table

    modes = args.mode or ["openvino-fp32", "openvino-bf16", "openvino-int8", "openvino-int8w"]
    tag = f"{args.sampler}{args.steps}" if args.sampler else "default"
    out = Path(args.out) if args.out else Path(args.run_dir) / f"tiers-{tag}"
    record = run_tiers(args.run_dir, modes, args.episodes, args.sampler, args.steps, out,
                       seed_start=args.seed_start, observations=args.observations, progress=not args.quiet)
    print(tiers_table(record))
    print(f"results: {out / 'tiers.json'}")
    return 0


def cmd_policies(args: argparse.Namespace) -> int:
    from bcbench.policies import REGISTRY, is_learned
    from bcbench.policies.outside import plugins

    print("built in (learned: train, then --checkpoint RUN_DIR; baselines: --policy NAME):")
    for name in REGISTRY:
        print(f"  {name:<12} {'learned' if is_learned(name) else 'baseline'}")
    found = plugins()
    print(f"plug-ins (entry-point group bcbench.policies): {'' if found else 'none installed'}")
    for name, ep in sorted(found.items()):
        dist = ep.dist.name if ep.dist else "?"
        print(f"  {name:<12} {ep.value}  (package {dist})")
    print("any other: --policy my_pkg.my_module:make_policy [--policy-arg KEY=VALUE ...]")
    return 0


def _latency_runners(args: argparse.Namespace) -> dict[str, Any]:
    """`latency --checkpoint`: each run or published model loaded as `eval --checkpoint` loads it (a published
    model in its recorded sampler setting unless --sampler/--steps name one)."""
    if not args.checkpoint:
        return {}
    if len(args.sampler or []) > 1 or len(args.steps or []) > 1:
        raise BCBenchError("with --checkpoint, give at most one --sampler and one --steps")
    from bcbench.cli.policies import eval_namespace

    first = lambda v: v[0] if v else None  # noqa: E731
    return {c: load_eval_policy(eval_namespace(checkpoint=c, sampler=first(args.sampler), steps=first(args.steps),
                                               device="cpu" if args.device == "auto" else args.device))[0]
            for c in args.checkpoint}


def cmd_latency(args: argparse.Namespace) -> int:
    from bcbench.analysis.figures import budgets, latency_bars
    from bcbench.evaluation.benchmark import run_latency_benchmark
    from bcbench.modes import BACKEND_MODES
    from bcbench.policies.outside import parse_kwargs

    modes = [BACKEND_MODES.get(m, m) for m in args.mode] if args.mode else None  # `eval --backend` names too
    out = run_latency_benchmark(policies=args.policy, presets=args.preset, modes=modes, steps=args.steps,
                                samplers=args.sampler, device=args.device, threads=args.threads,
                                rate_hz=args.rate, out=args.out, quick_timing=args.quick,
                                policy_args=parse_kwargs(args.policy_arg), runners=_latency_runners(args),
                                task=args.task)
    rec, plot = out["record"], Path(out["json"]).with_name("latency.png")
    hw = rec["hardware"]
    horizons = sorted({r["action_horizon"] for r in rec["rows"] if r.get("action_horizon")})
    latency_bars([{**r, "label": f"{r['policy']} {r['preset']} {r['variant']} {r['mode']}"} for r in rec["rows"]],
                 plot, f"Latency per call, batch 1 ({hw.get('gpu') or hw['cpu_model']}, {hw['torch_threads']} threads)",
                 budgets(rec["rate_hz"], horizons))  # every fresh row records its horizon
    print(f"latency results: {out['json']}  table: {out['table']}  plot: {plot}")
    return 0


def main(argv: list[str] | None = None) -> int:

    parser = build_parser()
    args = parser.parse_args(argv)
    # the data commands live in cli/data.py, serve and the wall-clock check in cli/wallclock.py
    handler = getattr(data, args.func, None) or getattr(wallclock, args.func, None) or globals()[args.func]
    git_commit()  # the code this process runs: read now, before anyone edits the tree (results carry it)
    try:
        return int(handler(args) or 0)
    except BCBenchError as exc:
        print(f"bcbench: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("bcbench: interrupted (finished results were written atomically; nothing half-written)",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # output piped into `head` and the like, which stopped reading: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes
        return 0


if __name__ == "__main__":
    sys.exit(main())
