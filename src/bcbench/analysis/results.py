"""Reading result files back: evaluations, latencies, training summaries, as flat rows for the report.

Only files are read (never a model): a results directory from `bcbench study`, plus any extra folders of
result JSON (e.g. `results/` brought back from a GPU machine), or the studies a combined report names
(`bcbench.analysis.studies`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bcbench.analysis.curves import Curve, load_curve, plateau
from bcbench.analysis.realtime import pool_training_seeds
from bcbench.analysis.studies import left_out_runs, run_files, study_dirs, study_files, study_roles
from bcbench.errors import BCBenchError
from bcbench.modes import EXACT_MODES
from bcbench.reference import sized_label
from bcbench.utils.io import read_json, read_jsonl

# Result files the report reads, by kind: every one records the commit its process ran.
_KINDS = (("eval-*.json", "evaluations"), ("eval.json", "evaluations"), ("check-*.json", "convergence checks"),
          ("latency-*.json", "timing"),
          ("train_summary.json", "training"), ("realtime-*.json", "real-time sweeps"), ("tiers.json", "tiers"),
          ("latency-paired*.json", "interleaved latency"))


def file_commits(results: Path, extra_dirs: list[str] | None = None) -> dict[str, list[str]]:
    """commit -> the kinds of result file produced at it, over every file the report reads (not only the
    evaluations): a study completed later with sweeps, re-timings or backend files shows each commit."""
    out: dict[str, set[str]] = {}
    skip = left_out_runs(results)
    for folder in dict.fromkeys([results, *study_dirs(results), *map(Path, extra_dirs or [])]):
        for pattern, kind in _KINDS:
            if kind == "interleaved latency" and folder != results:
                continue  # a combined report reads its own interleaved timings, not its studies'
            for f in folder.rglob(pattern):
                if ("report" in f.relative_to(folder).parts or f.name.startswith(".") or skip.intersection(f.parents)
                        or (kind == "timing" and f.name.startswith("latency-paired"))):
                    continue
                commit = read_json(f).get("git_commit") or "unknown"
                out.setdefault(commit, set()).add(kind)
    return {c: sorted(k) for c, k in sorted(out.items())}


@dataclass
class Row:
    """One evaluated policy setting with everything the report shows about it."""

    key: str  # unique: run folder + variant
    label: str
    policy: str
    preset: str | None
    variant: str  # "default", "ddpm10", ...
    sampler: str | None
    steps: int | None
    spacing: str | None  # diffusion: trailing or leading (files from before spacing was recorded: leading)
    beta_schedule: str | None
    params: int
    summary: dict[str, Any]
    scores: dict[int, float] = field(default_factory=dict)  # episode seed -> score, for paired comparisons
    git_commit: str | None = None
    curve: Curve | None = None  # learned policies: rollout scores and validation loss while training
    converged: bool | None = None  # None: not trained here (baselines)
    convergence: str = ""  # why (see bcbench.analysis.curves.plateau)
    check_verdict: str | None = None  # its twice-the-steps check's verdict, where it had one (analysis.convergence)
    latency: dict[str, Any] = field(default_factory=dict)  # mode -> stats
    train: dict[str, Any] = field(default_factory=dict)
    hardware: dict[str, Any] = field(default_factory=dict)
    timed_on: str | None = None  # the machine that timed it (recorded by studies; matters on a cluster)
    timed_hardware: dict[str, Any] = field(default_factory=dict)  # its latency record's CPU and threads
    timed_at: str = ""  # when (its latency record's `created`, ISO UTC): a label's newest timing is its sitting's
    source: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)  # dotted preset overrides (its run.json)
    preset_values: dict[str, Any] = field(default_factory=dict)  # the preset's value of each overridden key
    recipe: str = ""  # the optimiser recipe it trained with, from its run.json config (`recipe_text`)
    run_label: str = ""  # the study's label of its run (variants of one run share it)
    doubles: str | None = None  # this run checks the convergence of the run so labelled (twice its steps)
    train_seed: int | None = None  # the trained run's seed (None: a baseline)
    # a setting over several training seeds (bcbench.analysis.seeds): each seed's episode scores, its seed ids and
    # runs; empty for a single run, whose episode scores are `scores`
    seed_scores: list[dict[int, float]] = field(default_factory=list)
    seed_ids: list[int] = field(default_factory=list)
    task: str = "pusht"  # the task its episodes ran (a record from before tasks: Push-T)
    control_hz: float | None = 10.0  # its task's control rate (Push-T's 10 Hz for a record from before tasks; None:
    # another task's record from before the rate was recorded, which the analysis cannot know without its task)
    action_horizon: int | None = None  # the steps of each chunk it executes, from its config (None: not recorded)
    difficulty: str | None = None  # the task's published difficulty group, where its record names one
    data_split: dict[str, Any] = field(default_factory=dict)  # its run.json's (val_fraction, split_seed, demos)

    @property
    def setting(self) -> str:
        """'DP DDIM10': its label and, for a sampler setting, the variant (how tables and findings name it)."""
        return self.label + ("" if self.variant == "default" else f" {self.variant.upper()}")

    def est(self, name: str) -> dict[str, Any]:
        return self.summary[name]

    @property
    def score(self) -> float:
        return float(self.summary["mean_score"]["value"])

    def latency_ms(self, mode: str = "reference", stat: str = "median_ms") -> float | None:
        m = self.latency.get(mode) or self.latency.get("reference")
        return None if m is None else float(m[stat])

    def deployed_ms(self) -> tuple[str, float] | None:
        """The fastest exact non-reference mode in this row's latency record and its median, if timed."""
        timed = [(m, float(self.latency[m]["median_ms"])) for m in EXACT_MODES[1:] if m in self.latency]
        return min(timed, key=lambda t: t[1]) if timed else None

    @property
    def reference_key(self) -> str | None:
        """The published study's number to stand beside this row's: Push-T's only (None on another task)."""
        if self.task != "pusht":
            return None
        return f"{self.policy}:{self.variant}" if self.sampler else self.policy


def _row_from_eval(path: Path, margin: float = 0.05, role: dict[str, Any] | None = None) -> Row:
    ev = read_json(path)
    if ev.get("type") != "evaluation":
        raise BCBenchError(f"{path} is not an evaluation result")
    pol = ev["policy"]
    study = {**ev.get("study", {}), **(role or {})}
    variant = (study.get("variant") or {})
    sampler = pol.get("sampler") or variant.get("sampler")
    steps = pol.get("steps") or variant.get("steps")
    # spacing was recorded from the commit that made trailing the default; earlier files used leading
    spacing = (pol.get("spacing") or variant.get("spacing") or "leading") if sampler else None
    # a study names its files by variant (eval-ddim10.json); a lone `bcbench eval` writes eval.json
    prefix = "check-" if path.stem.startswith("check-") else "eval-"  # a confirm study's checks: check-VARIANT
    named = path.stem.startswith(prefix)
    vkey = path.stem[len(prefix):] if named else (
        f"{sampler}{steps}" + ("" if spacing == "trailing" else f"-{spacing}") if sampler else "default")
    cfg = pol.get("config", {})
    run_dir = path.parent
    params = int(pol.get("parameters", 0))
    label = sized_label(study.get("label") or pol["name"], pol["name"], params, cfg)
    if study.get("outside_policy"):  # a user's policy (module:factory or a plug-in): labelled as such everywhere
        label += f" (outside bcbench: {study['outside_policy']})"
    run_label, doubles = (study.get(k) and sized_label(study[k], pol["name"], params, cfg)
                          for k in ("label", "doubles"))
    row = Row(key=f"{run_dir.name}:{vkey}", label=label, policy=pol["name"], run_label=run_label or "",
              doubles=doubles or None,
              preset=pol.get("preset"), variant=vkey, sampler=sampler, steps=steps, spacing=spacing,
              beta_schedule=cfg.get("beta_schedule"), params=params, summary=ev["summary"],
              scores={int(e["seed"]): float(e["score"]) for e in ev.get("episodes", [])},
              git_commit=ev.get("git_commit"), hardware=ev.get("hardware", {}), source=str(path),
              train_seed=cfg.get("seed") if "run_dir" in pol else None,
              task=(ev.get("eval_config") or {}).get("task") or "pusht",
              difficulty=(ev.get("task") or {}).get("difficulty"),
              control_hz=_control_hz(ev),
              action_horizon=cfg.get("action_horizon"))
    lat = run_dir / f"latency-{vkey}.json"
    if lat.exists():
        record = read_json(lat)
        row.latency = record["modes"]
        row.timed_on, row.timed_hardware = record.get("node"), record.get("hardware") or {}
        row.timed_at = str(record.get("created") or "")
    if (run_dir / "run.json").exists():
        meta = read_json(run_dir / "run.json")
        row.overrides, row.preset_values = meta.get("overrides") or {}, meta.get("preset_values") or {}
        row.recipe = recipe_text((meta.get("config") or {}).get("optim") or {})
        row.data_split = meta.get("data_split") or {}
    if (run_dir / "train_summary.json").exists():
        row.train = read_json(run_dir / "train_summary.json")
        row.curve = load_curve(run_dir)
        row.converged, row.convergence = plateau(row.curve, margin)
    return row


def _control_hz(ev: dict[str, Any]) -> float | None:
    """An evaluation's task control rate: its record's, else Push-T's 10 Hz for a Push-T record, else unknown."""
    rate = (ev.get("task") or {}).get("control_hz")
    if rate:
        return float(rate)
    return 10.0 if ((ev.get("eval_config") or {}).get("task") or "pusht") == "pusht" else None


def recipe_text(optim: dict[str, Any]) -> str:
    """'adamw lr 0.0005, batch 64, 20,400 steps, cosine, 100 warm-up steps, fp32, EMA' from a run's optim config."""
    if not optim:
        return ""
    budget = f"{optim['max_steps']:,} steps" if optim.get("max_steps") else f"{optim.get('epochs')} epochs"
    parts = [f"{optim.get('optimizer')} lr {optim.get('lr'):g}", f"batch {optim.get('batch_size')}", budget,
             str(optim.get("schedule")), f"{optim.get('warmup_steps', 0)} warm-up steps", str(optim.get("precision")),
             *(["EMA"] if optim.get("ema") else []),
             # a plateau schedule reads each validation: their cadence is part of its recipe (elsewhere it is not)
             *([f"validation every {optim['val_every']} steps"] if optim.get("val_every") and
               optim.get("schedule") == "plateau" else [])]
    return ", ".join(parts)


def load_rows(results: str | Path, extra_dirs: list[str] | None = None, margin: float = 0.05) -> list[Row]:
    """Every evaluation under `results` (and the extra folders), newest file per key."""
    results = Path(results)
    if not results.is_dir():
        raise BCBenchError(f"results directory {results} not found")
    roles = {d: study_roles(d) for d in study_dirs(results)}  # once per study, not once per file
    files = [(f, roles[d]) for pattern in ("eval-*.json", "eval.json") for d, f in study_files(results, pattern)]
    files += [(f, {}) for d in extra_dirs or [] for f in sorted(Path(d).rglob("eval*.json"))]
    rows: dict[str, Row] = {}
    for f, roles in files:
        try:
            row = _row_from_eval(f, margin, roles.get(f.parent.name))
        except (KeyError, ValueError, BCBenchError):
            continue  # not an evaluation file of ours
        rows[row.key] = row
    if not rows:
        raise BCBenchError(f"no evaluation results under {results}")
    return list(rows.values())


def load_check_rows(results: str | Path) -> list[Row]:
    """A confirm study's twice-the-steps checks (runs/*/check-*.json, on validation episodes), one row each."""
    roles = {d: study_roles(d) for d in study_dirs(Path(results))}
    return [_row_from_eval(f, role=roles[d].get(f.parent.name)) for d, f in run_files(results, "check-*.json")]


def load_latency_files(dirs: list[str | Path]) -> list[dict[str, Any]]:
    """Stand-alone `bcbench latency` outputs (latency.json) found under the folders."""
    out = []
    for d in dirs:
        for f in sorted(Path(d).rglob("latency.json")):
            data = read_json(f)
            if data.get("type") == "latency-benchmark":
                data["source"] = str(f)
                out.append(data)
    return out


def realtime_records(results: str | Path) -> list[tuple[Path, dict[str, Any]]]:
    """Every real-time sweep record under `results` (runs/*/realtime-*.json of type realtime), with its file."""
    found = ((f, read_json(f)) for _, f in study_files(results, "realtime-*.json"))
    return [(f, data) for f, data in found if data.get("type") == "realtime"]


def sweep_label(f: Path, data: dict[str, Any]) -> str:
    """A real-time record's label: its study label (a strategy's sweep in a study ends in ' + STRATEGY'), the
    sampler and steps it ran, and an outside policy's name."""
    study, pol = data.get("study", {}), _sweep_policy(data)
    v = study.get("variant") or {}
    base = study.get("label", f.parent.name)
    if pol:  # named with its size, as its evaluation rows are
        base = sized_label(base, pol.get("name", ""), int(pol.get("parameters", 0)), pol.get("config"))
    label = base + (f" {v['sampler'].upper()}{v['steps']}" if v.get("sampler") else "")
    if study.get("outside_policy"):
        label += f" (outside bcbench: {study['outside_policy']})"
    return label


def _sweep_policy(data: dict[str, Any]) -> dict[str, Any]:
    """The policy record of a real-time sweep's first setting (every setting ran the same model)."""
    first = next(iter((data.get("settings") or {}).values()), {})
    return first.get("policy") or {} if isinstance(first, dict) else {}


def load_realtime(results: str | Path) -> dict[str, dict[str, Any]]:
    """Real-time sweeps of a study (runs/*/realtime-*.json): label -> {setting name: evaluation result}; a label
    swept with several training seeds gets one sweep pooled over them (`analysis.realtime.pool_training_seeds`)."""
    found: dict[str, list[dict[str, Any]]] = {}
    for f, data in realtime_records(results):
        found.setdefault(sweep_label(f, data), []).append(data["settings"])
    return {label: pool_training_seeds(sweeps) for label, sweeps in found.items()}


def weights_conflicts(results: str | Path) -> list[str]:
    """One warning per run whose records name more than one weights file (policy.weights_sha256, recorded since issue
    74), for the same checkpoint step and weights: two different models under one run folder, e.g. a folder replaced
    by a retrain, whose records a report would otherwise pool as one model."""
    seen: dict[tuple[str, str, str], dict[str, list[str]]] = {}
    for _, f in study_files(results, "*.json"):
        rec = read_json(f)
        records = [rec, *(rec.get("settings") or {}).values()] if isinstance(rec, dict) else []
        for r in records:
            pol = r.get("policy") if isinstance(r, dict) else None
            if isinstance(pol, dict) and pol.get("weights_sha256"):
                key = (Path(str(pol.get("run_dir", ""))).name, str(pol.get("checkpoint")), str(pol.get("weights")))
                seen.setdefault(key, {}).setdefault(pol["weights_sha256"], []).append(f.name)
    return [f"Warning: the records of {run} ({ckpt}, {kind} weights) name {len(h)} different weights files: "
            + "; ".join(f"sha256 {sha[:12]} in {', '.join(sorted(set(files))[:3])}" for sha, files in h.items())
            for (run, ckpt, kind), h in sorted(seen.items()) if len(h) > 1]


def study_time(results: str | Path) -> dict[str, float]:
    """Seconds a study spent, by kind of work, from its index.jsonl and its runs' training records.

    Training stages split into optimiser time (train_summary.json's train_time_s, summed over every session
    of a resumed run) and learning-curve rollouts (metrics.jsonl's eval_wall_s); the other stages count their
    recorded seconds. A stopped and resumed study has no single wall time: this is the sum of its work.
    """
    out = {"training": 0.0, "curve rollouts": 0.0, "evaluation": 0.0, "timing": 0.0, "real-time sweep": 0.0}
    kinds = {"eval": "evaluation", "check": "evaluation", "latency": "timing", "realtime": "real-time sweep"}
    for study, rec in index_lines(results):
        _add_stage(out, kinds, study, rec)
    return out


def index_lines(results: str | Path) -> Iterator[tuple[Path, dict[str, Any]]]:
    """(study folder, index.jsonl line) of every finished stage a report reads: each study's (a combined report's
    studies), less the runs it leaves out."""
    skip = left_out_runs(Path(results))
    for study in study_dirs(Path(results)):
        for rec in read_jsonl(study / "index.jsonl"):  # none: an empty list
            if not skip.intersection((study / rec.get("file", "")).parents):
                yield study, rec


def _add_stage(out: dict[str, float], kinds: dict[str, str], results: Path, rec: dict[str, Any]) -> None:
    """One index.jsonl line's recorded work, added to `out` by kind (training from the run's own records)."""
    if rec["stage"] in kinds:
        out[kinds[rec["stage"]]] += float(rec["seconds"])
    elif rec["stage"] == "train":
        run = (results / rec["file"]).parent
        out["training"] += float(read_json(run / "train_summary.json").get("train_time_s", 0.0))
        out["curve rollouts"] += load_curve(run).rollout_s


def cpu_text(h: dict[str, Any]) -> str:
    """A record's CPU as a reader needs it: model name, family and model where recorded (KVM's names are generic),
    ISA flags."""
    text = h.get("cpu_model", "?") + (f" [{h['cpu_id']}]" if h.get("cpu_id") else "")
    return text + (f" ({', '.join(h['cpu_flags'])})" if h.get("cpu_flags") else "")


def same_cpu_once(records: list[dict[str, Any]], key: Callable[[dict[str, Any]], Any] | None = None
                  ) -> list[dict[str, Any]]:
    """Hardware records with those written before cpu_id existed dropped where a record of the same key (model and
    flags unless given) has it: the same machine, so one CPU is not named twice."""
    key = key or (lambda h: (h.get("cpu_model"), tuple(h.get("cpu_flags") or ())))
    with_id = {key(h) for h in records if h.get("cpu_id")}
    return [h for h in records if h.get("cpu_id") or key(h) not in with_id]


def study_machines(results: str | Path) -> list[str]:
    """The CPUs (model and ISA flags) a study's training sessions, evaluations, timings and real-time sweeps ran on,
    from its records."""
    found: list[dict[str, Any]] = []
    for _, f in study_files(results, "*.json"):
        if f.name != "train_summary.json" and not f.name.startswith(("eval", "check", "latency", "realtime")):
            continue
        rec = read_json(f)
        found += [h for h in [*(rec.get("segments") or []), rec.get("hardware") or {}] if h.get("cpu_model")]
    return sorted({cpu_text(h) for h in same_cpu_once(found)})
