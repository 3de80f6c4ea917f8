"""`bcbench study SPEC.toml --ray [ADDRESS]`: the study's stages as Ray tasks, independent runs in parallel.

The driver (this process) keeps the in-process runner's layout and rules: it lists the stages whose result
files do not exist yet, submits each as a Ray task once what it needs is done (a run's evaluations and
timing wait for its training) and CPUs are free for it (evaluations of trained runs before further trainings:
`pick`), and writes every result file and `index.jsonl` line itself, atomically, as
tasks finish. So a study killed under Ray resumes under Ray or without it, and the other way round.

- Resources: each stage asks for the `cpus` / `gpus` of its kind in the spec's `resources` table
  (default: `threads` CPUs, no GPU). Training runs write checkpoints into OUT/runs/, so on a cluster OUT
  must be on storage every node sees (a shared filesystem).
- Timing stages (latency, realtime) take a whole node: every node offers `bcbench_node` = 1000 units, other
  stages take 1 and a timing stage takes all 1000, so nothing else runs beside it (concurrent work distorts
  latency). A local instance is started with it; a cluster's nodes need it too:
      ray start --head --resources '{"bcbench_node": 1000}'      (and the same on every worker node)
  Result files of timing stages record the node that measured them.
- A failed stage is reported by name and its dependents are skipped; other stages go on and keep their
  results; the command then exits non-zero, and a re-run retries what failed.
"""

from __future__ import annotations

import platform
import time
from dataclasses import asdict, replace
from typing import Any

from tqdm import tqdm

from bcbench.errors import BCBenchError
from bcbench.study.progress import LAUNCH_FILE
from bcbench.study.runner import StudyRunner
from bcbench.study.spec import RunSpec, StudySpec, Variant
from bcbench.utils.io import write_json
from bcbench.utils.system import git_commit

NODE_RESOURCE, NODE_UNITS = "bcbench_node", 1000
EXCLUSIVE = ("latency", "realtime")  # stages that must have their node to themselves
Stage = tuple[str, RunSpec, Variant | None]  # (stage, run, setting), as StudyRunner.stages lists them


def _ray() -> Any:
    try:
        import ray  # optional extra (bcbench[ray]); only for --ray
    except ImportError as e:
        raise BCBenchError(f"--ray needs the ray package (pip install 'bcbench[ray]'): {e}") from e
    return ray


def _execute(spec: StudySpec, out: str, data: str | None, stage: str, run_index: int,
             variant: Variant | None) -> dict[str, Any]:
    """One stage in a Ray worker: compute it and hand the record back (the driver writes it)."""
    git_commit()  # the worker's code, read before the stage runs (as the CLI does)
    cpus = spec.resources.get(stage_kind(stage), {}).get("cpus")
    if cpus:  # a stage given N CPUs runs N torch threads: two 1-CPU trainings side by side train 1.08-1.29x the
        # samples/s of one 2-thread training on a 2-core AMD EPYC (results/train-throughput/threads/)
        spec = replace(spec, threads=max(1, int(cpus)))
    runner = StudyRunner(spec, out, data, progress=False)
    started = time.monotonic()
    record = runner.compute(stage, spec.runs[run_index], variant)
    return {"record": record, "seconds": time.monotonic() - started, "node": platform.node()}


def stage_kind(stage: str) -> str:
    """The `resources` key a stage reads: a confirm study's twice-the-steps check is an evaluation."""
    return "eval" if stage == "check" else stage


def stage_cpus(spec: StudySpec, stage: str) -> float:
    return spec.resources.get(stage_kind(stage), {}).get("cpus", spec.threads or 1)


_RANK = {"eval": 0, "check": 0, "train": 1}  # then the timing stages (EXCLUSIVE), last


def pick(spec: StudySpec, ready: list[Stage], busy_cpus: float, capacity: float, others_left: bool) -> list[Stage]:
    """The ready stages to hand Ray now, as many as the free CPUs hold, most important first.

    Ray starts queued tasks of one shape roughly in the order they were submitted, so submitting every ready
    stage at once would queue a finished training's evaluations behind all the trainings submitted before
    them: its scores would land hours (a long study: sessions) later. So the driver keeps the queue itself:
    evaluations and checks of trained runs first, then trainings, each in the study's order; a stage wider
    than the whole cluster goes alone. Timing stages (EXCLUSIVE) go last, in one stretch, once nothing else is
    left, as in the in-process runner; Ray's node resource runs them one per node."""
    if not others_left:
        return [item for item in ready if item[0] in EXCLUSIVE]
    free, chosen = capacity - busy_cpus, []
    for item in sorted((i for i in ready if i[0] not in EXCLUSIVE), key=lambda i: _RANK[i[0]]):  # stable
        need = stage_cpus(spec, item[0])
        if need <= free or (busy_cpus == 0 and not chosen):
            chosen.append(item)
            free -= need
    return chosen


def _options(spec: StudySpec, stage: str) -> dict[str, Any]:
    res = spec.resources.get(stage_kind(stage), {})
    return {"num_cpus": stage_cpus(spec, stage), "num_gpus": res.get("gpus", 0),
            "resources": {NODE_RESOURCE: NODE_UNITS if stage in EXCLUSIVE else 1}, "max_retries": 0}


def _connect(ray: Any, address: str | None, cpus: int | None) -> bool:
    """Join ADDRESS ('auto' or host:port) or start a local instance; True if this call started Ray."""
    if ray.is_initialized():
        return False
    kw = {"include_dashboard": False, "log_to_driver": False, "logging_level": "WARNING"}
    if address:
        ray.init(address=address, **kw)
        if ray.cluster_resources().get(NODE_RESOURCE, 0) < NODE_UNITS:
            ray.shutdown()
            raise BCBenchError(f"the Ray cluster's nodes need the resource {NODE_RESOURCE}={NODE_UNITS} "
                               f"(ray start ... --resources '{{\"{NODE_RESOURCE}\": {NODE_UNITS}}}')")
    else:
        ray.init(num_cpus=cpus, resources={NODE_RESOURCE: NODE_UNITS}, **kw)
    return True


def run_on_ray(runner: StudyRunner, address: str | None = None, cpus: int | None = None) -> dict[str, Any]:
    """Run a StudyRunner's pending stages as Ray tasks; returns the same summary as StudyRunner.run."""

    ray = _ray()
    spec: StudySpec = runner.spec
    started_ray = _connect(ray, address, cpus)
    t0 = time.monotonic()
    runner.out.mkdir(parents=True, exist_ok=True)
    write_json(runner.out / "spec.json", {**asdict(spec), "runs": [asdict(r) for r in spec.runs]})
    # for `bcbench study --status`: the CPUs Ray has (a local instance's, or a cluster's), which set how many
    # trainings run side by side
    write_json(runner.out / LAUNCH_FILE, {"ray": True, "ray_cpus": int(ray.cluster_resources().get("CPU", 1))})
    stages = runner.stages()
    pending = [s for s in stages if not runner.is_done(*s)]
    untrained = {id(run) for stage, run, _ in pending if stage == "train"}
    remote = ray.remote(_execute)
    index = {id(r): i for i, r in enumerate(spec.runs)}
    in_flight: dict[Any, Stage] = {}
    failed: list[str] = []
    bar = tqdm(total=len(stages), initial=len(stages) - len(pending), desc=f"study {spec.name} (ray)",
               unit="stage", disable=not runner.progress)

    def label(stage: str, run: RunSpec, variant: Variant | None) -> str:
        return f"{stage} {run.label} s{run.seed}" + (f" {variant.key}" if variant and variant.sampler else "")

    capacity = float(ray.cluster_resources().get("CPU", 1))

    def submit_ready() -> None:
        ready = [p for p in pending if p[0] == "train" or id(p[1]) not in untrained]  # the rest wait for training
        busy = sum(stage_cpus(spec, s) for s, _, _ in in_flight.values())
        others_left = any(s not in EXCLUSIVE for s, _, _ in [*pending, *in_flight.values()])
        for item in pick(spec, ready, busy, capacity, others_left):
            stage, run, variant = item
            pending.remove(item)
            ref = remote.options(**_options(spec, stage)).remote(spec, str(runner.out), runner.data, stage,
                                                                 index[id(run)], variant)
            in_flight[ref] = item

    try:
        submit_ready()
        while in_flight:
            bar.set_postfix_str(f"finished {bar.n}, running on ray {len(in_flight)}, waiting {len(pending)}")
            (ref,), _ = ray.wait(list(in_flight), num_returns=1)
            stage, run, variant = in_flight.pop(ref)
            try:
                res = ray.get(ref)
            except Exception as exc:  # a task's failure: name the stage, keep the others going
                msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
                failed.append(f"{label(stage, run, variant)}: {msg}")
                print(f"bcbench: stage failed: {failed[-1]}", flush=True)
                if stage == "train":  # its evaluations and timing cannot run
                    pending[:] = [p for p in pending if p[1] is not run]
                submit_ready()  # its CPUs are free again
                continue
            runner.finish(stage, run, variant, res["record"], res["seconds"], res["node"])
            if stage == "train":
                untrained.discard(id(run))
            bar.update()
            submit_ready()
    finally:
        bar.close()
        for ref in in_flight:
            ray.cancel(ref, force=True)
        if started_ray:
            ray.shutdown()
    if failed:
        raise BCBenchError(f"{len(failed)} stage(s) failed (finished results are kept; re-run to retry): "
                           + "; ".join(failed))
    return {"stages": len(stages), "skipped": len(stages) - runner.executed, "executed": runner.executed,
            "seconds": time.monotonic() - t0, "out": str(runner.out)}
