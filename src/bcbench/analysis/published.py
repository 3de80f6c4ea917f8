"""The published models (models/*/model.json) and the committed evidence about each: reads files only.

A published model (`bcbench publish`) names the run and checkpoint its weights came from and the committed
evaluation it reproduces (`scores.file`: per-episode scores on the test seeds, with the sampler, steps and mode
that made them). `bcbench choose` pairs a few of those episodes with a live re-score here, and reads the score
the model keeps under real-time execution from the committed sweeps of the same weights: any real-time record
under results/ (a study's run folder, or a `bcbench realtime` folder) whose settings ran this run's checkpoint,
with the same sampler and steps, on the test seeds. Which weights a record ran is matched by the run folder's name
(or a path ending in models/NAME, where the sweep ran the published folder itself) and the checkpoint's step.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.protocol import SYNC_SETTING, TEST_SEED_START, delay_setting
from bcbench.utils.io import read_json

# one setting's own file beside a sweep (realtime-sync.json, realtime-async-d4.json): not a sweep record
_SETTING_FILE = re.compile(r"realtime-(sync|async|blocking)(-[a-z0-9]+)?\.json$")


@dataclass(frozen=True)
class Published:
    """One published model folder and what its model.json says."""

    name: str
    folder: Path
    record: dict[str, Any] = field(repr=False)

    @property
    def policy(self) -> str:
        return str(self.record["policy"])

    @property
    def scores(self) -> dict[str, Any]:
        return self.record.get("scores") or {}

    @property
    def setting(self) -> str:
        """The setting the committed score ran: "DDIM-10" for a generative policy, else its preset."""
        s = self.scores
        return f"{s['sampler'].upper()}-{s['steps']}" if s.get("sampler") else str(self.record.get("preset", "-"))

    def sampler(self) -> tuple[str | None, int | None, str | None]:
        """(sampler, steps, spacing) of the committed score: what `eval --checkpoint` runs by default."""
        s = self.scores
        return s.get("sampler"), s.get("steps"), s.get("spacing")


def published_models(models_dir: str | Path) -> list[Published]:
    """Every models/*/model.json, by name; a missing or empty folder is one clear error."""
    root = Path(models_dir)
    if not root.is_dir():
        raise BCBenchError(f"no models folder at {root} (the published models are in models/ of the repository)")
    found = [Published(f.parent.name, f.parent, read_json(f)) for f in sorted(root.glob("*/model.json"))]
    if not found:
        raise BCBenchError(f"{root} holds no published models (no */model.json; `bcbench publish` writes them)")
    return found


def model_record(folder: str | Path) -> dict[str, Any] | None:
    """A published model's model.json, or None for a run folder (which has none)."""
    f = Path(folder) / "model.json"
    return read_json(f) if f.is_file() else None


def repo_root(results_dir: str | Path) -> Path:
    """The repository a results folder lies in: a model's scores file is named relative to it (results/...)."""
    return Path(results_dir).resolve().parent


def committed_eval(model: Published, root: Path) -> tuple[dict[int, float], dict[str, Any]]:
    """The evaluation the model reproduces (its model.json's scores.file): episode seed -> committed score, and
    its mean score with the 95% interval."""
    path = root / model.scores.get("file", "")
    if not path.is_file():
        raise BCBenchError(f"{model.name}: its committed scores file {model.scores.get('file')} is not in {root}")
    data = read_json(path)
    return {e["seed"]: float(e["score"]) for e in data["episodes"]}, data["summary"]["mean_score"]


def reproduction(live: dict[int, float], committed: dict[int, float], tolerance: float = 1e-3) -> dict[str, Any]:
    """The live scores against the committed ones of the same seeds: exactly equal, equal within `tolerance`
    (floating point on another CPU or batch: the same trajectory; 1e-3, tests/test_publish.py's rule: matrix kernels
    round differently at another batch size), or how far apart (mean and largest)."""
    seeds = sorted(set(live) & set(committed))
    if not seeds:
        raise BCBenchError("no episode seed is both re-scored and committed")
    diffs = [live[s] - committed[s] for s in seeds]
    worst = max(abs(d) for d in diffs)
    verdict = "exactly" if worst == 0 else "within" if worst <= tolerance else "differs"
    return {"seeds": seeds, "live": [live[s] for s in seeds], "committed": [committed[s] for s in seeds],
            "mean_difference": sum(diffs) / len(diffs), "largest_difference": worst, "verdict": verdict,
            "tolerance": tolerance}


def reproduction_text(rep: dict[str, Any]) -> str:
    n = len(rep["seeds"])
    if rep["verdict"] == "exactly":
        return f"reproduces exactly ({n} episodes)"
    if rep["verdict"] == "within":
        return f"reproduces ({n} episodes, largest difference {rep['largest_difference']:.1e}: floating point)"
    return (f"differs: mean {rep['mean_difference']:+.3f}, largest {rep['largest_difference']:.3f} "
            f"over {n} episodes")


# ----------------------------------------------------------------------------- committed real-time sweeps


@dataclass(frozen=True)
class Sweep:
    """One committed real-time sweep of a published model's weights."""

    path: Path
    strategy: str
    horizon: int | None  # the async execution horizon s it ran (None: the default, 8 - d)
    settings: dict[str, Any] = field(repr=False)

    def at(self, d: int, execution: str = "async") -> dict[str, Any] | None:
        return self.settings.get(delay_setting(execution, d))


def sweep_records(results_dir: str | Path) -> list[tuple[Path, dict[str, Any]]]:
    """Every real-time sweep record under `results_dir` (type realtime), in path order."""
    out = []
    for f in sorted(Path(results_dir).rglob("realtime*.json")):
        if _SETTING_FILE.search(f.name):
            continue
        data = read_json(f)
        if isinstance(data, dict) and data.get("type") == "realtime" and data.get("settings"):
            out.append((f, data))
    return out


# strategies whose sweeps a published model alone cannot rerun: a correction head, or weights trained for `prefix`
UNPUBLISHED_PARTS = ("correction", "prefix")


def _same_weights(policy: dict[str, Any], model: Published) -> bool:
    """A record ran this model's weights: by their sha256 where the record names it (issue 74), else (older records)
    by the run folder's name, checkpoint step and EMA/raw weights."""
    if policy.get("weights_sha256"):
        return policy["weights_sha256"] == (model.record.get("file") or {}).get("sha256")
    src = model.record.get("source") or {}
    run_dir = str(policy.get("run_dir") or "").rstrip("/")
    named = run_dir.rsplit("/", 1)[-1] == src.get("run") or run_dir.endswith(f"models/{model.name}")
    return named and policy.get("checkpoint") == src.get("checkpoint") and policy.get("weights", "ema") == \
        model.record.get("weights", "ema")


def sweeps_of(model: Published, records: list[tuple[Path, dict[str, Any]]]) -> list[Sweep]:
    """The committed sweeps of this model's weights at its committed sampler setting on the test seeds; the sweeps
    of its own study's folder first (where its committed score comes from), then the others in path order."""
    sampler, steps, _ = model.sampler()
    home = str(Path(model.scores.get("file", "")).parent.parent.parent)  # results/STUDY of runs/RUN/eval-*.json
    out = []
    for f, data in records:
        first = next(iter(data["settings"].values()))
        policy, cfg = first.get("policy") or {}, first.get("eval_config") or {}
        if not _same_weights(policy, model) or cfg.get("seed_start") != model.scores.get("seed_start",
                                                                                           TEST_SEED_START):
            continue
        if sampler and (policy.get("sampler"), policy.get("steps")) != (sampler, steps):
            continue
        variant = (data.get("study") or {}).get("variant") or {}
        strategy = (cfg.get("strategy") or {})
        if variant.get("strategy") in UNPUBLISHED_PARTS or strategy.get("bid_weak"):
            continue  # needs a part models/ does not hold (a head, delay-trained weights, a weak policy)
        asyncs = [s for k, s in data["settings"].items() if k.startswith("realtime-async-d")]
        horizon = (asyncs[0].get("eval_config") or {}).get("execution_horizon") if asyncs else None
        out.append(Sweep(f, variant.get("strategy") or "naive", horizon, data["settings"]))
    return sorted(out, key=lambda s: (f"{home}/" not in str(s.path), str(s.path)))


def horizon_text(horizon: int | None, d: int, action_horizon: int = 8) -> str:
    return f"s = {horizon}" if horizon else f"s = {max(1, action_horizon - d)} = 8 - d"


def sync_of(sweeps: list[Sweep]) -> dict[str, Any] | None:
    return next((s.settings[SYNC_SETTING] for s in sweeps if SYNC_SETTING in s.settings), None)
