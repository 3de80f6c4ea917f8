"""Studies: a spec (spec.py) names runs and how to evaluate them; the runner (runner.py) trains, evaluates and
times them stage by stage, resumably, in this process or on Ray (on_ray.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.protocol import check_purpose
from bcbench.study.on_ray import run_on_ray
from bcbench.study.progress import LAUNCH_FILE
from bcbench.study.runner import StudyRunner
from bcbench.study.spec import StudySpec
from bcbench.tasks import get_task
from bcbench.utils.io import read_json, write_json

__all__ = ["StudyRunner", "StudySpec", "run_study"]


def run_study(spec: StudySpec, out: str | Path | None = None, data: str | None = None,
              progress: bool = True, ray: str | None = None, ray_cpus: int | None = None) -> dict[str, Any]:
    """Run a study in this process, or with ray = 'local' (a local Ray instance) / 'auto' / an address."""
    default = spec.name if spec.task == "pusht" else f"{spec.name}-{spec.task.replace('/', '-')}"
    out = (Path(out) if out else Path("runs") / "studies" / default).resolve()  # Ray workers: any cwd
    written = out / "spec.json"
    if written.is_file() and (was := read_json(written).get("task", "pusht")) != spec.task:
        raise BCBenchError(f"{out} holds a study of {was}, not {spec.task}: give another --out")
    if not spec.runs:
        raise BCBenchError("the study has no runs")
    problem = check_purpose(spec.purpose, spec.seed_start, spec.episodes)  # a spec built in code, not parsed
    if problem:
        raise BCBenchError(f"study {spec.name}: {problem}")
    runner = StudyRunner(spec, out, str(Path(data).resolve()) if data else None, progress)
    if any(stage == "train" and not runner.is_done(stage, run, v) for stage, run, v in runner.stages()):
        # a training to run needs the task's demonstrations: missing ones stop the study here, in one line, rather
        # than as one failure per training after the evaluations that need none (a new machine's empty cache)
        get_task(spec.task).dataset(runner.data)
    if ray is None:
        # for `bcbench study --status` (another process): trainings one at a time here (run_on_ray writes its own)
        write_json(out / LAUNCH_FILE, {"ray": False})
        return runner.run()
    return run_on_ray(runner, None if ray == "local" else ray, ray_cpus)
