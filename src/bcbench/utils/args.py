"""argparse with the project's error rule: a usage error is one line on stderr and exit status 2 (the `bcbench`
command line and the module entry points, e.g. `python -m bcbench.study.restore`, share it)."""

from __future__ import annotations

import argparse

EXIT_USAGE = 2


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error in one line instead of usage + message."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")
