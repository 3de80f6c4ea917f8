"""Tasks: the environments, their seeded resets, scores and demonstrations (`Task`, `get_task`), below policies.

`pusht` is the study's image Push-T; `metaworld/NAME` are MetaWorld manipulation tasks whose demonstrations a
scripted expert generates (`bcbench data generate`). A family's package is imported only when one of its tasks
is asked for, so that Push-T never loads MuJoCo.
"""

from __future__ import annotations

from typing import Any

from bcbench.errors import BCBenchError
from bcbench.tasks.spec import Episode, Task

DEFAULT_TASK = "pusht"
FAMILIES = ("pusht", "metaworld")

__all__ = [
    "DEFAULT_TASK",
    "FAMILIES",
    "Episode",
    "Task",
    "declared_task",
    "example_for",
    "get_task",
    "task_names",
    "task_of",
]


def get_task(name: str | None = None) -> Task:
    """The task called `name` (None: Push-T); an unknown name is one BCBenchError naming the choices."""
    name = name or DEFAULT_TASK
    if name == "pusht":
        from bcbench.tasks.pusht import TASK

        return TASK
    family, _, rest = name.partition("/")
    if family == "metaworld" and rest:
        from bcbench.tasks.metaworld import metaworld_task

        return metaworld_task(rest)
    raise BCBenchError(f"unknown task '{name}' (choose pusht or metaworld/NAME: {', '.join(task_names())})")


def declared_task(policy: object) -> str | None:
    """The name of the task a policy says it was made for (a trained runner's Task, an outside policy's `task`
    name), or None where it says none."""
    task = getattr(policy, "task", None)
    return task.name if isinstance(task, Task) else task if isinstance(task, str) else None


def task_of(policy: object) -> Task:
    """The task a policy was made for (`declared_task`), else Push-T."""
    task = getattr(policy, "task", None)
    return task if isinstance(task, Task) else get_task(declared_task(policy))


def example_for(policy: object, batch: int = 1, seed: int = 0) -> dict[str, Any]:
    """A random raw observation window for `policy` (timing, contract checks) in its task's shapes."""
    return task_of(policy).example_observation(batch, int(getattr(policy, "obs_horizon", 2)), seed)


def task_names() -> list[str]:
    """Every task bcbench has (MetaWorld's from its own table, without importing MuJoCo)."""
    from bcbench.tasks.metaworld.table import TASKS as METAWORLD

    return ["pusht", *(f"metaworld/{n}" for n in METAWORLD)]
