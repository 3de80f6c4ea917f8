"""Reading a real-time sweep: each delay's score against sync (paired), the largest safe delay, and the
highest control rate at which a policy keeps its sync score. Reads result records only (no torch)."""

from __future__ import annotations

import collections
import glob
import math
import re
import statistics
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.protocol import CONTROL_DT_S, MIN_CHOICE_EPISODES, SYNC_SETTING, delay_setting, policy_label
from bcbench.stats import Z95, episodes_to_show_within, over_training_seeds, paired_bootstrap
from bcbench.utils.io import read_json


def seed_scores(r: dict[str, Any]) -> dict[int, float]:
    return {e["seed"]: e["score"] for e in r["episodes"]}


def replicate_scores(group: str) -> list[dict[int, float]]:
    """Per-episode scores of each record of a group of replicates of one setting (the same episode seeds run with
    another noise or training seed), in sorted path order so that seed0, seed1, ... pair up across groups. `group`:
    comma-separated records or globs; a record is one setting's file, or a sweep's (`realtime-sweep.json`, a study's
    real-time stage) with the setting named after a colon: `RUN/realtime-ddim10.json:realtime-async-d8`."""
    refs = []
    for part in group.split(","):
        pattern, colon, setting = part.partition(":")
        refs += [path + colon + setting for path in glob.glob(pattern)] or [part]  # no match: named as given
    out = []
    for ref in sorted(refs):
        path, _, setting = ref.partition(":")
        if not Path(path).is_file():
            raise BCBenchError(f"no record '{path}'")
        data = read_json(path)
        if "settings" in data:  # a sweep: one of its settings
            if setting not in data["settings"]:
                raise BCBenchError(f"'{path}' is a sweep: name one of its settings after a colon "
                                   f"({', '.join(data['settings'])})")
            data = data["settings"][setting]
        out.append(seed_scores(data))
    if any(set(s) != set(out[0]) for s in out):
        raise BCBenchError(f"the records of '{group}' do not share their episode seeds: not replicates of one setting")
    return out


def averaged(replicates: list[dict[int, float]]) -> dict[int, float]:
    """Each episode seed's score averaged over its replicates: the unit the paired comparisons then resample."""
    return {k: sum(r[k] for r in replicates) / len(replicates) for k in replicates[0]}


def training_seed(r: dict[str, Any]) -> int:
    """The training seed of the model an evaluation record ran (0 for a baseline, which has none)."""
    return int(((r.get("policy") or {}).get("config") or {}).get("seed") or 0)


def pool_training_seeds(sweeps: list[dict[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """One policy's sweeps, one per training seed, as one sweep: each setting every seed ran, its mean score the
    mean over training seeds with a t interval over the training seeds (`bcbench.stats.over_training_seeds`; the
    two-level bootstrap's beside it), its per-seed episode scores kept under "by_training_seed" so that
    `compare` pairs within a training seed. The measured call time is the median of the seeds' medians (the
    slowest call: the slowest of any), and the delays their calls took are counted over every seed."""
    if len(sweeps) == 1:
        return sweeps[0]
    sweeps = sorted(sweeps, key=lambda s: training_seed(next(iter(s.values()))))
    out: dict[str, dict[str, Any]] = {}
    for name in [n for n in sweeps[0] if all(n in s for s in sweeps)]:
        rs = [s[name] for s in sweeps]
        by_seed = [seed_scores(r) for r in rs]
        est = over_training_seeds(by_seed)
        summary = {**rs[0]["summary"], "n": sum(len(r["episodes"]) for r in rs),
                   "mean_score": {"value": est["value"], "ci95": est["ci95"], "ci95_bootstrap": est["ci95_bootstrap"]},
                   "training_seeds": [training_seed(r) for r in rs], "per_training_seed": est["per_seed"]}
        steps: collections.Counter[str] = collections.Counter()
        for r in rs:
            steps.update(r["summary"].get("delay_steps") or {})
        if steps:
            summary["delay_steps"] = dict(steps)
        if "median_ms" in (src := rs[0]["summary"].get("latency_source") or {}):
            calls = [r["summary"]["latency_source"] for r in rs]
            summary["latency_source"] = {**src, "median_ms": statistics.median(c["median_ms"] for c in calls),
                                         "max_ms": max(c["max_ms"] for c in calls)}
        episodes = [{**e, "training_seed": training_seed(r)} for r in rs for e in r["episodes"]]
        out[name] = {**rs[0], "summary": summary, "episodes": episodes, "by_training_seed": by_seed}
    return out


def compare(a: dict[str, Any], b: dict[str, Any]) -> tuple[float, float, float, int]:
    """a's score minus b's, paired over the episode seeds they share, with its 95% interval and the number of
    pairs. Pooled over training seeds (`pool_training_seeds`): paired within each training seed, a t interval over the
    training seeds' paired differences (`bcbench.stats.over_training_seeds`), so it includes training-seed variance."""
    if "by_training_seed" in a and "by_training_seed" in b:
        pooled = over_training_seeds(a["by_training_seed"], [b["by_training_seed"]])
        pairs = sum(len(set(x) & set(y)) for x, y in zip(a["by_training_seed"], b["by_training_seed"], strict=True))
        return pooled["value"], *pooled["ci95"], pairs
    return paired_bootstrap(seed_scores(a), [seed_scores(b)])


def paired_differences(a: dict[str, Any], b: dict[str, Any]) -> list[float]:
    """a's per-episode scores minus b's on the episode seeds they share; within each training seed when pooled."""
    if "by_training_seed" in a and "by_training_seed" in b:
        pairs = list(zip(a["by_training_seed"], b["by_training_seed"], strict=True))
    else:
        pairs = [(seed_scores(a), seed_scores(b))]
    return [x[k] - y[k] for x, y in pairs for k in sorted(set(x) & set(y))]


def margin_power_sentence(realtime: dict[str, dict[str, Any]], margin: float) -> str:
    """How wide a fixed delay's interval against sync is at the episodes swept, and how many paired episodes would
    show a setting that is truly as good as sync within the margin (80% power): why "not shown within the margin"
    is, by itself, no evidence of a loss. Reads every swept policy's fixed-delay settings whose estimate is within
    the margin of sync ("" where none is)."""
    found: list[tuple[float, float, int, bool]] = []  # (|mean difference|, its SD, pairs, pooled) per setting
    for settings in realtime.values():
        if SYNC_SETTING not in settings:
            continue
        for name, r in settings.items():
            if re.search(r"-d\d+$", name) and len(diffs := paired_differences(r, settings[SYNC_SETTING])) > 1:
                found.append((abs(statistics.mean(diffs)), statistics.stdev(diffs), len(diffs),
                              "by_training_seed" in r))
    # the spread of a setting near sync, the case the question is about (a large loss widens it): the settings
    # whose estimate is within the margin; none such, nothing to say
    near = [f for f in found if f[0] <= margin]
    if not near:
        return ""
    sds = [f[1] for f in near]
    sd, n = statistics.median(sds), int(statistics.median(f[2] for f in near))
    half = Z95 * sd / math.sqrt(n)
    need = [math.ceil(episodes_to_show_within(x, margin)) for x in (min(sds), max(sds))]
    which = f"the {len(near)} delayed setting{'s' if len(near) > 1 else ''} whose estimate is within the margin"
    spread = f"{sd:.2f}" if len(sds) == 1 else f"{min(sds):.2f}-{max(sds):.2f} (median {sd:.2f})"
    episodes = f"{need[0]}" if need[0] == need[1] else f"{need[0]}-{need[1]}"
    return (f"What the margin asks of {n} paired episodes: the per-episode differences to sync of {which} have a "
            f"standard deviation of {spread}, so a 95% interval reaches "
            f"about +/-{half:.3f} around its estimate" + (" (episode variance only)" if any(f[3] for f in near) else "")
            + f", and a setting is shown within the margin only where its estimate is above {half - margin:+.3f}"
            + (" (better than sync)" if half >= margin else "") + f". A setting truly as good as sync needs about "
            f"{episodes} paired episodes (training seeds x test episodes) to be shown so with 80% power: "
            "'not shown within the margin' is by itself no evidence of a loss; the paired difference is.")


def pooled_sentence(sweeps: dict[str, dict[str, dict[str, Any]]]) -> str:
    """Which of the policies' sweeps are pooled over training seeds, and what that does to the numbers; and that
    the others are of one trained model each, whose intervals say nothing of other training seeds (issue 74)."""
    seeds = {label: next(iter(s.values()))["summary"]["training_seeds"] for label, s in sweeps.items()
             if s and "training_seeds" in next(iter(s.values()))["summary"]}
    single = len([s for s in sweeps.values() if s]) - len(seeds)
    one = ((f"{'The other' if seeds else 'Every'} sweep{'s are' if single > 1 or not seeds else ' is'} of one trained "
            "model (one training seed): its intervals are over episode seeds only and say nothing of other training "
            "seeds, so a strategy shown to keep or recover a score here is shown so for that model.") if single
           else "")
    if not seeds:
        return one
    named = "; ".join(f"{label}: {', '.join(map(str, ids))}" for label, ids in seeds.items())
    return (f"Swept with several training seeds ({named}): each score is the mean over those seeds, and every "
            "interval and paired difference resamples training seeds and, within each, episodes (differences "
            "paired within a training seed)." + (f" {one}" if one else ""))


def delay_vs_sync(results: dict[str, dict[str, Any]], setting: str) -> tuple[float, float, float, int]:
    """A setting's score minus sync over shared seeds, with its 95% paired-bootstrap interval and n seeds."""
    return compare(results[setting], results[SYNC_SETTING])


def largest_safe_delay(results: dict[str, dict[str, Any]], execution: str, margin: float) -> int | None:
    """The largest d whose score stays within the margin of sync (paired: the interval of d minus sync lies
    above -margin) for every delay up to it; None without a sync result."""
    if SYNC_SETTING not in results:
        return None
    safe = 0
    delays = sorted(int(k.rsplit("-d", 1)[1]) for k in results if k.startswith(f"realtime-{execution}-d"))
    for d in delays:
        if delay_vs_sync(results, delay_setting(execution, d))[1] <= -margin:
            break
        safe = d
    return safe


def strategy_of(results: dict[str, dict[str, Any]]) -> str:
    """The execution strategy a sweep ran, from its own records ("naive" for records from before strategies)."""
    first = next(iter(results.values()), {})
    return (first.get("summary", {}).get("strategy") or {}).get("strategy", "naive")


def with_plain_sync(settings: dict[str, Any], plain: dict[str, Any]) -> dict[str, Any]:
    """A strategy's sweep with its policy's plain sync score (the naive sweep's d = 0) in place of its own: the bar
    its safe delay is judged against, so that a strategy which lowers the sync score is not called safe against its
    own lower bar."""
    return {**settings, SYNC_SETTING: plain[SYNC_SETTING]}


def naive_sweep_of(realtime: dict[str, dict[str, Any]], label: str) -> dict[str, Any] | None:
    """The naive sweep "P" beside a strategy's sweep "P + ensemble" (its strategy read from its records); None for a
    naive sweep, or where no naive sweep with a sync setting is beside it."""
    kind = strategy_of(realtime[label])
    plain = realtime.get(policy_label(label, kind)) if kind != "naive" else None
    return plain if plain is not None and strategy_of(plain) == "naive" and SYNC_SETTING in plain else None


def delay_curve(results: dict[str, dict[str, Any]], execution: str) -> list[tuple[int, dict[str, Any]]]:
    """(d, mean-score estimate) of one execution mode, with sync as d = 0."""
    pts = [(0, results[SYNC_SETTING]["summary"]["mean_score"])] if SYNC_SETTING in results else []
    prefix = f"realtime-{execution}-d"
    pts += sorted((int(k[len(prefix):]), r["summary"]["mean_score"]) for k, r in results.items()
                  if k.startswith(prefix))
    return pts


def highest_safe_rate(safe_d: int | None, latency_ms: float) -> float | None:
    """The highest control rate (Hz) at which calls of `latency_ms` stay within `safe_d` steps of delay.

    At rate f a call of L seconds takes d = ceil(L f) steps, so d <= safe_d for every f <= safe_d / L. This
    reads the score-against-delay curve, measured in 10 Hz steps, as holding in steps at other rates too
    (Diffusion Policy's Fig. 6 and Real-Time Chunking count delay in steps the same way). 0: no real-time
    rate is shown to keep the score (not even one step of delay is shown within the margin); None: no sweep to read.
    """
    if safe_d is None:
        return None
    return safe_d / (latency_ms / 1e3) if latency_ms > 0 else math.inf


def too_few_episodes(settings: dict[str, dict[str, Any]]) -> int | None:
    """The episodes per setting of a sweep too small to give a safe-delay verdict (fewer than the protocol's
    MIN_CHOICE_EPISODES: at 5 episodes a delay that scored 0.99 against sync 0.69 was called unsafe), else None."""
    n = min(int(r["summary"].get("n", len(r.get("episodes") or []))) for r in settings.values())
    return n if n < MIN_CHOICE_EPISODES else None


def step_rate(records: Iterable[dict[str, Any]]) -> tuple[float, str]:
    """The control rate a sweep counts delay in, and its task in words, from its records' `task` (Push-T's 10 Hz
    for a record written before tasks existed); `records`: a sweep's (its settings' values) or several sweeps'."""
    for r in records:
        task = r.get("task")
        if isinstance(task, dict) and task.get("name", "pusht") != "pusht":
            return float(task["control_hz"]), str(task["name"])
    return 1 / CONTROL_DT_S, "Push-T"


def rate_text(hz: float, extra: str = "", step: tuple[float, str] = (1 / CONTROL_DT_S, "Push-T")) -> str:
    """A safe control rate, capped at what the simulator shows: delay is counted in Push-T's 10 Hz steps, so a
    rate above 10 Hz says only that the calls would allow it ("10 Hz (Push-T's step rate; calls alone allow 5599
    Hz)"); `extra` goes inside the same parentheses; `step`: the sweep's step rate and task (`step_rate`)."""
    top, task = step
    if hz <= top + 1e-9:
        return f"{hz:.1f} Hz" + (f" ({extra})" if extra else "")
    return f"{top:g} Hz ({task}'s step rate; calls alone allow {hz:.0f} Hz" + (f"; {extra})" if extra else ")")


def safe_delay_sentence(settings: dict[str, dict[str, Any]], margin: float, plain: dict[str, Any] | None = None
                        ) -> str:
    """One policy's largest safe delay per execution mode and, from the better mode's measured setting, its
    highest safe control rate; where no delay is shown safe, the d = 1 differences that say why. `plain`: for a
    strategy's sweep, its policy's naive sweep, whose sync score it is judged against (and says so)."""
    if plain is not None:
        return (f"Against the plain sync score ({plain[SYNC_SETTING]['summary']['mean_score']['value']:.3f}, naive's), "
                "as in the strategies' table: " + safe_delay_sentence(with_plain_sync(settings, plain), margin))
    if SYNC_SETTING not in settings:
        return ""
    if (few := too_few_episodes(settings)) is not None:
        return f"Largest safe delay and highest safe control rate: too few episodes to decide ({few})."
    safe = {e: largest_safe_delay(settings, e, margin) for e in ("async", "blocking")
            if any(k.startswith(f"realtime-{e}-d") for k in settings)}

    def minus_sync(modes: Any, setting: str) -> str:  # "async -0.036 [-0.106, +0.031]; blocking ..."
        keys = [(e, f"realtime-{e}-{setting}") for e in modes if f"realtime-{e}-{setting}" in settings]
        return "; ".join(f"{e} {est:+.3f} [{lo:+.3f}, {hi:+.3f}]"
                         for e, k in keys for est, lo, hi, _ in [delay_vs_sync(settings, k)])

    if not safe:  # e.g. a backend's sweep: sync and measured only
        diffs = minus_sync(("async", "blocking"), "measured")
        return f"At its measured latency, minus sync: {diffs}." if diffs else ""
    head = "Largest safe delay: " + ", ".join(f"{e} d = {d}" for e, d in safe.items())
    mode, best = max(safe.items(), key=lambda kv: kv[1])  # ties: async, listed first
    if best == 0:  # why: the smallest delay swept (d = 1 unless the sweep skipped it)
        first = min(int(k.rsplit("-d", 1)[1]) for e in safe for k in settings if k.startswith(f"realtime-{e}-d"))
        return (f"{head}: no delay is shown within the margin (d = {first} minus sync: "
                f"{minus_sync(safe, f'd{first}')}), so no real-time control rate is shown to keep its sync score.")
    measured = settings.get(f"realtime-{mode}-measured", {}).get("summary", {}).get("latency_source", {})
    fits = ""
    if measured:
        med, slow = (highest_safe_rate(best, measured[k]) for k in ("median_ms", "max_ms"))
        top, task = step_rate(settings.values())
        fits = (f"; its measured median call {measured['median_ms']:.0f} ms "
                f"{'fits' if med >= top else 'does not fit'} within {mode} d = {best} at {top:g} Hz; "
                f"highest safe control rate {min(med, top):.1f} Hz ({min(slow, top):.1f} Hz at its slowest call), "
                f"{mode}"
                + (f" (capped at {task}'s {top:g} Hz step rate, in which the sweep counts delay: the calls alone would "
                   f"allow {med:.0f} Hz, {slow:.0f} Hz at the slowest)" if med > top else ""))
    return f"{head}{fits}."
