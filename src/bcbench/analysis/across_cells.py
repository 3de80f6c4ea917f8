"""How the report across tasks (analysis.across) names a setting and fills a cell of its first table: one row per
setting across tasks (its size, which moves with the task's shapes, left out of the match), the parts of a name every
learned row shares said once, and each cell's success [interval] and latency. Reads rows only."""

from __future__ import annotations

import re

from bcbench.analysis.baseline import UNTRAINED
from bcbench.analysis.results import Row
from bcbench.stats import wilson

ORDER = ["random", "scripted", "cnn_mlp", "resnet50", "bet", "bct", "diffusion", "flow"]  # the table's row order


_SIZE = re.compile(r"\((\d+\.\d+) M")  # the parameter count a sized label carries: "1/4 width (5.34 M"


def setting_key(r: Row) -> tuple[str, str]:
    """A setting is the same across tasks by its study label and variant, its size left out: the size moves with the
    task's shapes (pick-place's goal in the proprioception makes DP's network 5.37 M where drawer-open's is 5.34 M)."""
    return (_SIZE.sub("(", r.run_label or r.label), r.variant)


def setting_name(rows: list[Row]) -> tuple[str, str]:
    """A row's name, as (label, variant suffix): the setting as its first task names it, or, where its size differs
    between tasks, with the range: "..., 1/4 width (5.34-5.37 M by task)"."""
    sizes = sorted({m.group(1) for r in rows if (m := _SIZE.search(r.label))}, key=float)
    label, suffix = rows[0].label, rows[0].setting[len(rows[0].label):]  # suffix: " DDIM10", or ""
    return (label if len(sizes) < 2 else _SIZE.sub(f"({sizes[0]}-{sizes[-1]} M by task", label, count=1)), suffix


def success(r: Row) -> tuple[float, float, float, str]:
    """A setting's success rate, its 95% interval and how it was formed. On a task scored by success (MetaWorld) the
    mean score is the success rate: Wilson over the episodes for one run, the report's interval over training seeds
    (t, widened to the episodes' where the seeds agree: bcbench.stats.over_training_seeds) for several. On Push-T
    (scored by coverage) the success share is read instead, pooled over the seeds' episodes with Wilson's interval
    (the pooled interval ignores the training seeds' spread: said so)."""
    n = int(r.summary.get("n") or len(r.scores))
    if r.seed_scores and r.task != "pusht":
        v, (lo, hi) = r.summary["mean_score"]["value"], r.summary["mean_score"]["ci95"]
        return v, max(lo, 0.0), min(hi, 1.0), f"{len(r.seed_scores)} training seeds"
    v = float(r.summary.get("success_rate", r.summary["mean_score"])["value"])
    lo, hi = wilson(round(v * n), n)
    how = ("no training" if baseline(r) else
           f"{len(r.seed_scores)} training seeds, episodes pooled" if r.seed_scores else "1 training seed")
    return v, lo, hi, how


def success_cell(r: Row) -> str:
    """'92.0% [81.2, 96.8], 1 training seed' or '85.3% [78.0, 92.6], 3 training seeds'."""
    v, lo, hi, how = success(r)
    return f"{100 * v:.1f}% [{100 * lo:.1f}, {100 * hi:.1f}], {how}"


def latency_cell(r: Row) -> str:
    fast = r.deployed_ms()
    if fast:
        return f"{fast[1]:.1f} ms ({fast[0]})"
    ref = r.latency_ms("reference")
    return "not timed" if ref is None else f"{ref:.1f} ms (reference)"


def baseline(r: Row) -> bool:
    """An untrained baseline (random, scripted): its name keeps every part (the note speaks of learned rows)."""
    return r.policy in UNTRAINED


def _parts(label: str) -> list[str]:
    """A label split at its top-level commas: "ResNet-50 CNN, 10 demos, 1/8 width (0.48 M, random init)" has 3."""
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(label):
        depth = max(0, depth + (ch == "(") - (ch == ")"))  # a stray ")" must not stop later commas splitting
        if ch == "," and depth == 0:
            parts.append(label[start:i].strip())
            start = i + 1
    return [*parts, label[start:].strip()]


def common_parts(labels: list[str]) -> list[str]:
    """The parts of a setting's label that every learned row shares ("10 demos", "horizons 4 / 3"), said once under
    the table rather than in every row (the table has to fit a laptop's first screen). The policy's own name (the
    first part) always stays; two rows at least."""
    if len(labels) < 2:
        return []
    split = [_parts(x) for x in labels]
    return list(dict.fromkeys(p for p in split[0][1:] if all(p in parts[1:] for parts in split[1:])))


def without(label: str, shared: list[str]) -> str:
    parts = _parts(label)
    return ", ".join([parts[0], *(p for p in parts[1:] if p not in shared)])
