"""Option helpers of the `bcbench` parser modules (`parser`, `parser_data`): validated number types, options that
take a config field's default and help (`_field`), and the shared --task and --data flags. Like the parser, this
module imports no torch and no commands.
"""

from __future__ import annotations

import argparse
from typing import Any

from bcbench.utils.fields import field_default, field_docs


def _number(kind: type, minimum: float, strict: bool = False) -> Any:
    """An argparse type: a number of `kind` that is >= minimum (> minimum when strict), else a clear error."""
    noun = "a whole number" if kind is int else "a number"
    bound = f"{'>' if strict else '>='} {minimum:g}"

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun}, got '{text}'") from None
        if value < minimum or (strict and value == minimum):
            raise argparse.ArgumentTypeError(f"expected a number {bound}, got {value}")
        return value

    return parse


_positive_int = _number(int, 1)
_nonneg_int = _number(int, 0)
_positive_float = _number(float, 0, strict=True)


def _field(p: argparse.ArgumentParser, flag: str, cls: type, name: str | None = None, **kw: Any) -> None:
    """An option whose default and help are a config dataclass field's own (written once, under the field)."""
    name = name or flag.lstrip("-").replace("-", "_")
    default = kw.pop("default", field_default(cls, name))
    flag_only = kw.get("action") in ("store_true", "store_false")  # its presence says it all
    shown = f" (default {default})" if default not in (None, False) and not flag_only else ""
    p.add_argument(flag, default=default, help=field_docs(cls)[name] + shown, **kw)


def _add_task_flag(p: argparse.ArgumentParser, trained: bool = False) -> None:
    """--task, one help for every command that takes it; `trained`: the default is the run's own task."""
    p.add_argument("--task", metavar="NAME", default=None if trained else "pusht",
                   help="pusht or metaworld/NAME (`bcbench data tasks` lists them); default "
                        + ("a trained run's own task, else pusht" if trained else "pusht"))


def _add_data_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", metavar="ZARR", help="dataset folder (default: $BCBENCH_DATA, then ../shared beside "
                   "the repo, then the `bcbench data fetch` location)")
