"""The arguments of `bcbench data ...`: fetch, info, replay, export, import, and generate and tasks for the tasks
whose experts are scripted. Handlers are named, not imported (as in `bcbench.cli.parser`): no torch, no commands.
"""

from __future__ import annotations

from typing import Any

from bcbench.cli.options import _add_data_flag, _add_task_flag, _nonneg_int, _number, _positive_int
from bcbench.utils.args import OneLineParser


def _add_task_data_commands(dsub: Any) -> None:
    """`data generate` and `data tasks`: demonstrations of the tasks whose experts are scripted (MetaWorld)."""
    p = dsub.add_parser("generate", help="generate a task's demonstrations with its scripted expert (MetaWorld)")
    p.add_argument("--task", metavar="NAME", required=True, help="metaworld/NAME (`bcbench data tasks` lists them)")
    p.add_argument("--episodes", type=_positive_int, required=True, metavar="N", help="successful episodes to keep")
    p.add_argument("--out", metavar="ZARR", help="the replay buffer to write (default: the task's own place, where "
                   "train and eval look for it)")
    p.add_argument("--seed-start", type=_nonneg_int, default=0, help="first demonstration seed (default 0; never the "
                   "test seeds 100000-100099 or validation seeds 200000+)")
    p.add_argument("--noise", type=_number(float, 0), default=0.0, metavar="STD",
                   help="Gaussian noise of this std added to the expert's actions, seeded per episode (default 0)")
    p.add_argument("--workers", type=_positive_int, metavar="N", help="processes (default: one per core)")
    p.add_argument("--force", action="store_true", help="replace an existing buffer at --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func="cmd_data_generate")
    p = dsub.add_parser("tasks", help="the tasks bcbench has: observation, action, cap, demonstrations")
    p.set_defaults(func="cmd_data_tasks")


def _add_data_commands(sub: Any) -> None:
    data = sub.add_parser("data", help="get, generate, inspect and replay demonstrations")
    dsub = data.add_subparsers(dest="data_command", metavar="DATA_COMMAND", parser_class=OneLineParser)
    dsub.required = True
    _add_task_data_commands(dsub)
    p = dsub.add_parser("fetch", help="download the official pusht.zip (or import a local copy) and verify it")
    p.add_argument("--from", dest="source", metavar="ZIP_OR_DIR",
                   help="import this zip or folder instead of downloading")
    p.add_argument("--dest", metavar="DIR",
                   help="where the zarr folder goes (default: ~/.cache/bcbench/data/pusht/...)")
    p.add_argument("--url", help="download address (default: the Diffusion Policy project's pusht.zip)")
    p.add_argument("--force", action="store_true", help="replace an existing dataset at --dest")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func="cmd_data_fetch")
    p = dsub.add_parser("info", help="validate a task's demonstrations and print their summary")
    _add_task_flag(p)
    _add_data_flag(p)
    p.add_argument("--no-images", action="store_true", help="skip reading the image store (fast)")
    p.set_defaults(func="cmd_data_info")
    p = dsub.add_parser("replay", help="replay every demonstration open-loop: simulator exactness and the "
                        "demonstrators' score")
    _add_data_flag(p)
    p.add_argument("--episodes", type=_positive_int, metavar="N", help="only the first N episodes")
    p.add_argument("--workers", type=_positive_int, metavar="N", help="processes (default: one per core)")
    p.add_argument("--out", metavar="FILE", help="write the JSON report here")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func="cmd_data_replay")
    p = dsub.add_parser("export", help="write a task's demonstrations as a LeRobot v3.0 dataset (lossless frames)")
    _add_task_flag(p)
    _add_data_flag(p)
    p.add_argument("--to", dest="fmt", choices=["lerobot"], required=True, help="the format: lerobot (v3.0)")
    p.add_argument("dest", metavar="DIR", help="the dataset folder to write")
    p.add_argument("--video", action="store_true", help="frames as AV1 video, as the Hub's lerobot/pusht (lossy)")
    p.add_argument("--force", action="store_true", help="replace an existing folder at DIR")
    p.set_defaults(func="cmd_data_export")
    p = dsub.add_parser("import", help="read a task's LeRobot v3.0 dataset into a bcbench replay buffer (zarr)")
    _add_task_flag(p)
    p.add_argument("--from", dest="fmt", choices=["lerobot"], required=True, help="the format: lerobot (v3.0)")
    p.add_argument("source", metavar="DIR", help="the LeRobot dataset folder (parquet + AV1 video or PNG frames)")
    p.add_argument("--out", metavar="ZARR", required=True, help="the replay buffer to write (train with --data ZARR)")
    p.add_argument("--force", action="store_true", help="replace an existing folder at --out")
    p.set_defaults(func="cmd_data_import")
