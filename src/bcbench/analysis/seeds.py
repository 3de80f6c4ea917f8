"""Settings over several training seeds: one row per setting, its score a mean over training seeds.

A confirm study trains each preset with several seeds (`seeds = [0, 1, 2]`) and evaluates every seed on the same
test episodes. The report then shows a setting (policy label + sampler variant) once: the mean over training seeds
of each seed's mean episode score, with a t interval over the training seeds' means (bcbench.stats.over_training_seeds:
with three seeds a bootstrap over them covers too rarely) and the two-level bootstrap's beside it, and each seed's
own score. Shares (> 0.5, > 0.9, success) pool the episodes of all seeds. Latency is that of the seed timed last
(the seeds share one network architecture and its cost; a study times one seed, its lowest, but a restored study
whose seed 0 weights stayed behind may time seed 1 in a later sitting: scripts/study_stages.py --any-seed
--again). A study with one seed per setting is returned unchanged, so its report reads exactly as before.
"""

from __future__ import annotations

from dataclasses import replace

from bcbench.analysis.results import Row
from bcbench.stats import over_training_seeds

SHARES = ("share_above_0.5", "share_above_0.9", "success_rate")


def merge_training_seeds(rows: list[Row]) -> list[Row]:
    """Rows of one setting (same label, policy and variant; distinct training seeds) merged into one row each, in
    the order the settings first appear."""
    groups: dict[tuple[str, str, str], list[Row]] = {}
    for r in rows:
        groups.setdefault((r.label, r.policy, r.variant), []).append(r)
    out = []
    for group in groups.values():
        seeds = [r.train_seed for r in group]
        if len(group) == 1 or None in seeds or len(set(seeds)) != len(seeds):
            out.extend(group)  # one run, a baseline, or repeated seeds (not a seed replicate): shown as they are
        else:
            out.append(_merged(sorted(group, key=lambda r: r.train_seed)))
    return out


def _merged(group: list[Row]) -> Row:
    first = group[0]
    # the newest timing of the group (group: by seed, so equal times give the lowest seed): a task's networks are
    # timed again in one sitting (study_stages.py --again), on whichever seed's weights are here (--any-seed)
    timed = max((r for r in group if r.latency), key=lambda r: r.timed_at, default=first)
    est = over_training_seeds([r.scores for r in group])
    n = sum(len(r.scores) for r in group)
    summary = {**first.summary, "n": n, "mean_score": {"value": est["value"], "ci95": est["ci95"],
                                                       "ci95_bootstrap": est["ci95_bootstrap"]},
               "training_seeds": len(group), "training_seed_share": est["training_seed_share"],
               "per_seed": est["per_seed"]}
    for k in SHARES:  # pooled over every seed's episodes
        if all(k in r.summary for r in group):
            summary[k] = {"value": sum(r.summary[k]["value"] * len(r.scores) for r in group) / n, "ci95": None}
    return replace(first, key=f"{first.key.split(':')[0]}+{len(group) - 1}:{first.variant}", summary=summary,
                   scores={}, seed_scores=[dict(r.scores) for r in group],
                   seed_ids=[int(r.train_seed) for r in group if r.train_seed is not None],
                   latency=timed.latency, timed_on=timed.timed_on, timed_hardware=timed.timed_hardware,
                   timed_at=timed.timed_at,
                   converged=None if any(r.converged is None for r in group) else all(r.converged for r in group))


def per_seed_cell(r: Row) -> str:
    """'s0 0.712, s1 0.684, s2 0.741 (training seeds: 31% of variance; two-level bootstrap [0.69, 0.73])' for a
    merged row; '-' for a single run."""
    if not r.seed_scores:
        return "-"
    scores = ", ".join(f"s{i} {v:.3f}" for i, v in zip(r.seed_ids, r.summary["per_seed"], strict=True))
    boot = r.summary["mean_score"].get("ci95_bootstrap")
    boot_txt = f"; two-level bootstrap [{boot[0]:.3f}, {boot[1]:.3f}]" if boot else ""
    return f"{scores} (training seeds: {100 * r.summary['training_seed_share']:.0f}% of variance{boot_txt})"


def episodes_and_seeds(rows: list[Row]) -> tuple[list[int], list[int], list[int]]:
    """Episode counts per run, the episode seeds, and the training-seed counts per setting, over `rows` (merged or
    not)."""
    per_run = [sc for r in rows for sc in (r.seed_scores or ([r.scores] if r.scores else []))]
    several = {len(r.seed_scores) for r in rows if r.seed_scores}
    # beside settings with several seeds, a trained setting with one (a stage still running) counts as 1
    one = {1 for r in rows if not r.seed_scores and r.converged is not None} if several else set()
    return (sorted({len(sc) for sc in per_run}), sorted({s for sc in per_run for s in sc}), sorted(several | one))
