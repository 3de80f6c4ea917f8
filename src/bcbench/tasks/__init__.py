"""Tasks: the environments, their seeded resets, scores and demonstrations (`Task`, `get_task`), below policies.

`pusht` is the study's image Push-T; `metaworld/NAME` are MetaWorld manipulation tasks whose demonstrations a
scripted expert generates (`bcbench data generate`). A family's package is imported only when one of its tasks
is asked for, so that Push-T never loads MuJoCo.
"""

from __future__ import annotations

from bcbench.errors import BCBenchError
from bcbench.tasks.spec import Episode, Task

DEFAULT_TASK = "pusht"
FAMILIES = ("pusht", "metaworld")

__all__ = ["DEFAULT_TASK", "FAMILIES", "Episode", "Task", "get_task", "task_names"]


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


def task_names() -> list[str]:
    """Every task bcbench has (MetaWorld's from its own table, without importing MuJoCo)."""
    from bcbench.tasks.metaworld.table import TASKS as METAWORLD

    return ["pusht", *(f"metaworld/{n}" for n in METAWORLD)]
