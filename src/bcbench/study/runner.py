"""`bcbench study SPEC.toml`: train, evaluate and time every run of a study; resumable stage by stage.

Layout of a results directory:

    OUT/spec.json                         the parsed spec
    OUT/index.jsonl                       one line per finished stage (the report's table of contents)
    OUT/runs/KEY/                         a training run (KEY = policy-config-sSEED-CONFIGHASH), or a
                                          baseline's folder; inside: eval-VARIANT.json, latency-VARIANT.json

A stage whose result file exists is skipped, so an interrupted study (Ctrl-C, kill, crash) resumes where
it stopped; a training stage resumes from its newest checkpoint. Every file is written atomically.
"""

from __future__ import annotations

import hashlib
import json
import platform
import time
from dataclasses import asdict, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm

from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.config import StrategyConfig, torch_only
from bcbench.evaluation.evaluate import EvalConfig, evaluate
from bcbench.evaluation.realtime import realtime_record, sweep
from bcbench.evaluation.timing import TimingConfig, latency_record
from bcbench.interface import ChunkPolicy
from bcbench.modes import mode_name
from bcbench.policies import make_policy
from bcbench.policies.checkpoint import configure_runner, load_runner
from bcbench.policies.outside import outside_policy
from bcbench.protocol import VALIDATION_SEED_START, strategy_label, training_done
from bcbench.study.spec import RunSpec, StudySpec, Variant
from bcbench.tasks import get_task
from bcbench.training.loop import TrainOptions, new_run, train
from bcbench.utils.device import pick_device
from bcbench.utils.io import append_jsonl, read_json, safe_name, write_json


class StudyRunner:
    def __init__(self, spec: StudySpec, out: str | Path, data: str | None = None, progress: bool = True) -> None:
        self.spec, self.out, self.data, self.progress = spec, Path(out), data, progress
        self.executed = 0  # stages executed (not skipped) in this process
        self.device = str(pick_device(spec.device))  # training, evaluation and timing all run here

    # ------------------------------------------------------------------ layout
    def run_dir(self, run: RunSpec) -> Path:
        if run.learned:
            key = run.key(self.spec.val_fraction, self.spec.task)
        elif run.outside:  # its factory arguments are part of what was run
            h = hashlib.sha256(json.dumps(run.args, sort_keys=True).encode()).hexdigest()[:8]
            key = f"{safe_name(run.policy)}-s{run.seed}-{h}-outside"
        else:
            key = f"{run.policy}-{run.config}-s{run.seed}-baseline"
        return self.out / "runs" / key

    def stages(self) -> list[tuple[str, RunSpec, Variant | None]]:
        """Every run's training and evaluations first, then all timing: timing is done last, in one stretch,
        so a machine kept quiet for it is not disturbed by the study's own training in between."""
        out: list[tuple[str, RunSpec, Variant | None]] = []
        shown = [run for run in self.spec.runs if self.spec.shown(run)]
        for run in self.spec.runs:
            if run.learned:
                out.append(("train", run, None))
            if self.spec.shown(run):
                out += [("eval", run, v) for v in run.variants]
            if self.spec.checks_on_validation(run):
                out += [("check", run, v) for v in run.variants]
        if self.spec.latency:  # one training seed per label: the time of an exact mode does not depend on weights
            lowest = {r.label: min(x.seed for x in shown if x.label == r.label) for r in shown}
            out += [("latency", run, v) for run in shown if run.seed == lowest[run.label] for v in run.variants]
        if self.spec.realtime:  # last: its 'measured' setting times the policy too; one sweep per strategy
            kinds = self.spec.realtime.get("strategies", ["naive"])
            out += [("realtime", run, replace(v, strategy=None if k == "naive" else k))
                    for run in shown for v in run.realtime for k in kinds]
        return out

    def result_file(self, stage: str, run: RunSpec, variant: Variant | None) -> Path:
        d = self.run_dir(run)
        if stage == "train":
            return d / "train_summary.json"
        return d / f"{stage}-{variant.key}.json"

    def partial_file(self, run: RunSpec, variant: Variant) -> Path:
        """The finished settings of an interrupted real-time sweep (hidden: no report or export reads it)."""
        return self.run_dir(run) / f".realtime-{variant.key}.partial.json"

    def is_done(self, stage: str, run: RunSpec, variant: Variant | None) -> bool:
        f = self.result_file(stage, run, variant)
        if not f.exists():
            return False
        if stage == "check":  # a check re-sized in the spec runs again, on the new count of episodes
            return read_json(f)["eval_config"]["episodes"] == self.spec.check_size(run)
        return stage != "train" or training_done(read_json(f))

    # ------------------------------------------------------------------ stages
    def _train(self, run: RunSpec) -> None:
        opts = TrainOptions(max_minutes=run.max_minutes, threads=self.spec.threads, data=self.data,
                            val_fraction=self.spec.val_fraction, progress=self.progress, device=self.device,
                            eval_every=run.eval_every, eval_episodes=self.spec.curve_episodes, demos=run.demos)
        d = self.run_dir(run)
        if not (d / "run.json").exists():
            new_run(run.policy, run.config, {**run.overrides, "seed": run.seed}, d, opts, self.spec.task)
        summary = train(d, opts)
        if not training_done(summary):
            raise KeyboardInterrupt  # Ctrl-C during training: the checkpoint is saved; stop the study here

    def _policy(self, run: RunSpec, variant: Variant, torch_only: str = "") -> ChunkPolicy:
        if run.outside:
            return outside_policy(run.policy, run.args)
        if not run.learned:
            return make_policy(run.policy, run.config, get_task(self.spec.task), seed=run.seed)
        runner = load_runner(self.run_dir(run), use_ema=True, device=self.device)
        configure_runner(runner, variant.sampler, variant.steps, run.seed, variant.spacing)
        apply_mode(runner, mode_name(self.spec.backend, self.spec.precision), torch_only=torch_only)
        return runner

    def _eval(self, run: RunSpec, variant: Variant, check: bool = False) -> dict[str, Any]:
        episodes, start = (self.spec.check_size(run), VALIDATION_SEED_START) if check else (
            self.spec.episodes, self.spec.seed_start)
        cfg = EvalConfig(episodes=episodes, seed_start=start, max_steps=self.spec.max_steps, task=self.spec.task)
        extra = {"study": {"name": self.spec.name, "purpose": self.spec.purpose, **({"check": True} if check else {}),
                           "label": run.label,
                           "variant": asdict(variant), "run_dir": str(self.run_dir(run)),
                           **({"outside_policy": run.policy, "args": run.args} if run.outside else {}),
                           **({"doubles": run.doubles} if run.doubles else {})}}
        return evaluate(self._policy(run, variant), cfg, None, progress=self.progress, extra=extra)

    def _check(self, run: RunSpec, variant: Variant) -> dict[str, Any]:
        """A confirm study's twice-the-steps check: the run on validation episodes (compared by the report with
        the run of the same seed it doubles, or that doubles it), never on the test seeds."""
        return self._eval(run, variant, check=True)

    def _latency(self, run: RunSpec, variant: Variant) -> dict[str, Any]:
        if self.spec.threads:
            torch.set_num_threads(self.spec.threads)
        timing = TimingConfig(min_calls=self.spec.latency_min_calls, min_seconds=self.spec.latency_min_seconds,
                              max_calls=max(200, self.spec.latency_min_calls))
        rec = latency_record(self._policy(run, variant), timing, self.spec.rate_hz, self.spec.latency_modes)
        rec["study"] = {"name": self.spec.name, "label": run.label, "variant": asdict(variant)}
        rec["node"] = platform.node()  # which machine timed it (a cluster has several)
        return rec

    def _realtime(self, run: RunSpec, variant: Variant) -> dict[str, Any]:
        rt = self.spec.realtime or {}
        partial = self.partial_file(run, variant)
        kind = variant.strategy or "naive"
        strategy = StrategyConfig(kind, rtc_jacobian=rt.get("rtc_jacobian", True))
        policy = self._policy(run, variant, torch_only([kind], strategy.rtc_jacobian))  # auto: the paper's rtc in torch
        settings = sweep(policy, rt["delays"], rt["executions"], self.spec.episodes,
                         rt["profiles"], rt["measured"], self.progress, self.spec.max_steps, self.spec.seed_start,
                         skip_missing_profiles=True,  # e.g. the study gives no A100 time for BeT
                         done=read_json(partial) if partial.exists() else None,
                         on_setting=lambda results: write_json(partial, results),
                         execution_horizon=rt.get("execution_horizon"), strategy=strategy, task=self.spec.task)
        extra = {**asdict(variant), "strategy": kind, **strategy.variant_extra()}
        return realtime_record(settings, self.spec.name, strategy_label(run.label, kind), extra, self.spec.margin,
                               self.device, run.policy if run.outside else None)

    def after_stage(self) -> None:
        """Called after each executed stage (not after a skipped one); does nothing. The extension point for
        watching a study from code: subclass the runner and override it (the resume tests kill it here)."""

    # ------------------------------------------------------------------ driver
    def compute(self, stage: str, run: RunSpec, variant: Variant | None) -> dict[str, Any] | None:
        """Run one stage and return its result record (training writes its own run folder: None)."""
        if stage == "train":
            self._train(run)
            return None
        return getattr(self, f"_{stage}")(run, variant)

    def finish(self, stage: str, run: RunSpec, variant: Variant | None, record: dict[str, Any] | None,
               seconds: float, node: str | None = None) -> None:
        """Write a finished stage's result file and its index line (atomically, in this process)."""
        if record is not None:
            write_json(self.result_file(stage, run, variant), record)
        if stage == "realtime":
            self.partial_file(run, variant).unlink(missing_ok=True)  # only once the whole sweep is written
        append_jsonl(self.out / "index.jsonl", {
            "stage": stage, "run": self.run_dir(run).name, "policy": run.policy, "config": run.config,
            "seed": run.seed, "variant": variant.key if variant else None,
            "file": str(self.result_file(stage, run, variant).relative_to(self.out)),
            "seconds": round(seconds, 2), "finished": datetime.now(UTC).isoformat(timespec="seconds"),
            **({"node": node} if node else {}),
        })
        self.executed += 1

    def run(self) -> dict[str, Any]:
        self.out.mkdir(parents=True, exist_ok=True)
        write_json(self.out / "spec.json", {**asdict(self.spec), "runs": [asdict(r) for r in self.spec.runs]})
        stages = self.stages()
        t0 = time.monotonic()
        bar = tqdm(total=len(stages), desc=f"study {self.spec.name}", unit="stage", position=0,
                   disable=not self.progress)
        skipped = 0
        for stage, run, variant in stages:
            label = f"{stage} {run.label} s{run.seed}" + (f" {variant.key}" if variant and variant.sampler else "")
            bar.set_postfix_str(label)
            if self.is_done(stage, run, variant):
                skipped += 1
                bar.update()
                continue
            started = time.monotonic()
            self.finish(stage, run, variant, self.compute(stage, run, variant), time.monotonic() - started)
            bar.update()
            self.after_stage()
        bar.close()
        return {"stages": len(stages), "skipped": skipped, "executed": self.executed,
                "seconds": time.monotonic() - t0, "out": str(self.out)}
