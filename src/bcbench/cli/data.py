"""`bcbench data ...`: fetch, inspect, export, import and replay the demonstrations (handlers of bcbench.cli.main;
each imports the stage it runs, as there)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.stats import fmt_estimate, fmt_share
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


def cmd_data_fetch(args: argparse.Namespace) -> int:
    from bcbench.data.fetch import fetch
    from bcbench.data.paths import OFFICIAL_URL

    summary = fetch(args.source, args.dest, url=args.url or OFFICIAL_URL, force=args.force, progress=not args.quiet)
    _print_summary(summary)
    print(f"dataset ready: {summary['path']}  (use --data {summary['path']} or set BCBENCH_DATA)")
    return 0


def _print_summary(s: dict[str, Any]) -> None:
    el = s["episode_length"]
    print(f"{s['path']}\n  episodes {s['episodes']}, steps {s['steps']}, episode length "
          f"{el['min']}..{el['max']} (mean {el['mean']}), images {s['images']} {s['image_dtype'] or ''}")


def cmd_data_info(args: argparse.Namespace) -> int:
    from bcbench.tasks import get_task

    buf = get_task(args.task).demonstrations(args.data, images=not args.no_images)
    _print_summary(buf.summary())
    return 0


def cmd_data_export(args: argparse.Namespace) -> int:
    from bcbench.data.lerobot_format import export_lerobot
    from bcbench.tasks import get_task

    task = get_task(args.task)
    buf = task.demonstrations(args.data, images=True)
    info = export_lerobot(buf, args.dest, video=args.video, force=args.force, task=task)
    print(f"wrote LeRobot v3.0 dataset {info['path']}: {info['episodes']} episodes, {info['frames']} frames, "
          f"{info['frames_stored_as']}")
    return 0


def cmd_data_import(args: argparse.Namespace) -> int:
    from bcbench.data.lerobot_import import import_lerobot
    from bcbench.data.replay_buffer import write_replay_buffer
    from bcbench.tasks import get_task
    from bcbench.utils.io import atomic_dir

    task = get_task(args.task)
    buf = import_lerobot(args.source, task=task)
    if buf.keypoint is None or buf.n_contacts is None:  # write_replay_buffer writes Push-T's layout only
        raise BCBenchError(f"{args.source}: read as {task.name}'s demonstrations, but bcbench writes Push-T's "
                           "replay-buffer layout only (keypoints and contacts); nothing written")
    with atomic_dir(args.out, force=args.force) as staged:
        write_replay_buffer(staged, buf)
    _print_summary({**buf.summary(), "path": args.out})
    if buf.missing:
        print(f"  note: the dataset has no {', '.join('bcbench.' + m for m in buf.missing)}: zeros stand in (training "
              "on images works; `bcbench data replay` needs the block pose)")
    return 0


def cmd_data_replay(args: argparse.Namespace) -> int:
    from bcbench.data import load_replay_buffer, resolve_dataset
    from bcbench.tasks.pusht.replay import replay_buffer_episodes, replay_report

    buf = load_replay_buffer(resolve_dataset(args.data), images=False)
    if "block_pose" in buf.missing:
        raise BCBenchError(f"{buf.source} has no block pose (imported from a dataset without it): nothing to replay")
    episodes = list(range(buf.n_episodes))[: args.episodes] if args.episodes else None
    results = replay_buffer_episodes(buf, episodes, workers=args.workers, progress=not args.quiet)
    report = replay_report(results)
    report["dataset"] = buf.source

    report.update(provenance())  # commit, machine, versions: the claim in the README points here
    d, e = report["demonstrators"], report["block_error_px"]
    print(f"replayed {report['episodes']} episodes open-loop from their recorded start states")
    print(f"  exact (block within {report['exact_threshold_px']:g} px of the record all episode): "
          f"{report['exact_episodes']}/{report['episodes']} = {100 * report['exact_fraction']:.1f}%")
    print(f"  block position error px: median {e['median']:.3g}, p95 {e['p95']:.3g}, max {e['max']:.3g}")
    print(f"  demonstrators' score (the ceiling for cloning): mean {fmt_estimate(d['mean_score'])}")
    n = report["episodes"]
    print(f"    > 0.5: {fmt_share(d['share_above_0.5'], n)}   > 0.9: {fmt_share(d['share_above_0.9'], n)}   "
          f"success: {fmt_share(d['success_rate'], n)}")
    if args.out:
        write_json(args.out, report)
        print(f"  report written to {args.out}")
    if report["exact_fraction"] < 0.95:
        print("bcbench: error: fewer than 95% of episodes replay exactly: the simulator differs from the "
              "one that recorded the data", file=sys.stderr)
        return 1
    return 0


def cmd_data_generate(args: argparse.Namespace) -> int:
    from bcbench.tasks import get_task

    task = get_task(args.task)
    if task.family != "metaworld":
        raise BCBenchError(f"{task.name} has recorded demonstrations, not a scripted expert: `bcbench data fetch`")
    from bcbench.tasks.metaworld import default_dataset_path
    from bcbench.tasks.metaworld.generate import generate

    short = task.name.split("/", 1)[1]
    out = Path(args.out) if args.out else default_dataset_path(short)
    info = generate(short, args.episodes, out, seed_start=args.seed_start, noise=args.noise, workers=args.workers,
                    progress=not args.quiet, force=args.force)
    print(f"{task.name}: kept {info['episodes']} of {info['attempted']} scripted episodes (expert success "
          f"{info['scripted_success_rate']:.0%}), {info['steps']} steps in {info['seconds']:.0f} s on "
          f"{info['workers']} workers -> {out}")
    return 0


def cmd_data_tasks(args: argparse.Namespace) -> int:
    from bcbench.tasks import get_task, task_names

    for name in task_names():
        t = get_task(name)
        try:
            where, have = str(t.dataset(None)), "yes"
        except BCBenchError:
            where, have = "-", "no (bcbench data generate / fetch)"
        print(f"{name:<28} {t.difficulty or '-':<10} image {t.image_size}px ({t.camera}), state "
              f"{','.join(t.state_names)}; action {','.join(t.action_names)}; {t.control_hz:g} Hz, cap {t.max_steps}"
              f"\n{'':<28} demonstrations: {have} {where if have == 'yes' else ''}")
    return 0
