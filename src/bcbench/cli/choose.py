"""`bcbench choose`: the command that answers "which policy for my control loop, on this machine" from the published
models. It wires the stages: the analysis reads models/ and the committed results (bcbench.analysis.published,
.choose, .choose_page), the evaluation runs the policies here (bcbench.evaluation.choose). Policies the user adds
go through `bcbench eval --policy`'s own resolution (bcbench.cli.policies.load_eval_policy), so a plug-in, a
module:factory or a lerobot:FOLDER is taken exactly as there. Heavy imports are inside the handler (see main)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from bcbench.cli.policies import eval_namespace, load_eval_policy
from bcbench.errors import BCBenchError
from bcbench.tasks import task_of


def _policies(args: argparse.Namespace, models: list[Any]) -> dict[str, tuple[Any, Any]]:
    """label -> (policy, its Published model or None): every published model in the setting of its committed score
    (`eval --checkpoint models/NAME`'s default), then each --policy, checked before anything is timed."""
    out: dict[str, tuple[Any, Any]] = {}
    for name in args.policy or []:  # the user's first: a bad name fails in a second, not after the models load
        policy, _ = load_eval_policy(eval_namespace(policy=name, policy_arg=args.policy_arg))
        label = policy.name if policy.name not in out else name
        out[label] = (policy, None)
    loaded = {m.name: (load_eval_policy(eval_namespace(checkpoint=str(m.folder)))[0], m) for m in models}
    other = sorted(k for k, (p, _) in loaded.items() if task_of(p).name != "pusht")
    if other:  # the choice reads Push-T's committed sweeps at its 10 Hz: another task's model has no place in it
        print(f"choose: leaving out {', '.join(other)} (not Push-T models)", file=sys.stderr)
    return {**{k: v for k, v in loaded.items() if k not in other}, **out}


def cmd_choose(args: argparse.Namespace) -> int:
    from bcbench.analysis.choose import choice, with_evidence
    from bcbench.analysis.choose_page import console_table, write_page
    from bcbench.analysis.published import published_models, repo_root, sweep_records
    from bcbench.evaluation.choose import ChooseConfig, rescore, rollout_video, time_policies
    from bcbench.utils.system import provenance

    cfg = ChooseConfig(episodes=args.episodes, calls=args.calls, rate_hz=args.rate, threads=args.threads,
                       video=not args.no_video)
    models = published_models(args.models)  # a missing or empty folder: one line, before anything loads
    if not Path(args.results).is_dir():
        raise BCBenchError(f"no committed results at {args.results} (the real-time sweeps are read from there)")
    say = (lambda *_: None) if args.quiet else print
    policies = _policies(args, models)
    say(f"choose: {len(policies)} policies; timing each at batch 1 in every exact mode ({cfg.calls} calls each)")
    timing = time_policies({k: p for k, (p, _) in policies.items()}, cfg, progress=not args.quiet)
    root, records = repo_root(args.results), sweep_records(args.results)
    rows = []
    for label, (policy, model) in policies.items():
        seed_start, max_steps = ((model.scores.get("seed_start", 100_000), model.scores.get("max_steps", 300))
                                 if model else (100_000, 300))
        say(f"  re-scoring {label} on {cfg.episodes} test episodes from seed {seed_start}")
        m = {"label": label, "policy": model.policy if model else policy.name,
             "setting": _sized_setting(model) if model else "as given", "source": str(model.folder) if model else label,
             **timing["policies"][label],
             "live": rescore(policy, cfg.episodes, seed_start, max_steps, progress=False)}
        rows.append(with_evidence(m, model, records, root, cfg.rate_hz))
        say(f"    {rows[-1].get('rescored', '-')}")
    prov = provenance("cpu")
    pick = choice(rows, cfg.rate_hz, prov["hardware"]["cpu_model"])
    out = Path(args.out)
    video = None
    if cfg.video and pick["chosen"]:
        best = next(r for r in rows if r["label"] == pick["chosen"])
        rt = best.get("realtime") or {}
        say(f"  recording a rollout of {pick['chosen']}")
        video = rollout_video(policies[pick["chosen"]][0], out / "rollout", best["d"], rt.get("strategy", "naive"),
                              rt.get("horizon"))
    record = {"type": "choose", "rate_hz": cfg.rate_hz, "episodes": cfg.episodes, "choice": pick, "rows": rows,
              "timing": {k: v for k, v in timing.items() if k != "policies"}, "video": video, "root": str(root),
              "models": str(args.models), "results": str(args.results), **prov}
    paths = write_page(record, out)
    print(console_table(record))
    print(f"page: {paths['html']}  (Markdown: {paths['markdown']}; record: {paths['json']})")
    return 0


def _sized_setting(model: Any) -> str:
    """The published setting with the network's size where it is not the study's ("DDIM-10; 1/4 width (5.33 M)"):
    a folder named resnet50-cpu is a miniature, and the table says so (issue 74)."""
    from bcbench.reference import sized_label
    from bcbench.utils.io import read_json

    run = model.folder / "run.json"
    cfg = read_json(run).get("config") if run.is_file() else None
    size = sized_label("", model.policy, int(model.record.get("parameters") or 0), cfg).lstrip(", ")
    return f"{model.setting}; {size}" if size else model.setting
