"""Which study folders and runs a report reads: a study's own folder, or the folders a combined report names.

A combined report's folder holds `combine.json`, which names the study folders it reads (e.g. issue 30's confirm
stages, one study per stage); each keeps its own spec, so each run plays the part its own study gave it. It may leave
some runs of a study out (`leave_out`, by their labels), e.g. a policy whose second round, a study of its own,
replaces its first: the rounds share a run key (the first round's twice-the-steps run is the second's seed 0) and a
label, so reading both would count one model twice and pool two recipes as one setting.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.protocol import MIXING_REASON, test_informed_entries
from bcbench.utils.io import read_json

ACROSS_FILE = "across.json"  # a report across tasks: one study folder per task, read side by side (analysis.across)
COMBINE_FILE = "combine.json"  # {"studies": ["../a", "../b"], "why": "...", "leave_out": {"../a": ["label"]},
#                                  "chosen_by": {"label": "the study that chose its preset, and the seeds it read"},
#                                  "test_informed": [{"about": "label or stage", "decision": "...", "read": "file"}]}


def combined(results: Path) -> dict[str, Any] | None:
    """A combined report's combine.json (validated), or None for a study's own folder."""
    return _combination(Path(results))[0]


def _combination(results: Path) -> tuple[dict[str, Any] | None, set[Path]]:
    """combine.json validated, with the run folders it leaves out; (None, empty) for a study's own folder."""
    f = results / COMBINE_FILE
    if not f.exists():
        return None, set()
    spec = read_json(f)
    names = spec.get("studies") if isinstance(spec, dict) else None
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise BCBenchError(f"{f}: 'studies' must list the study folders it combines (paths relative to it)")
    for n in names:
        if not (results / n / "spec.json").is_file():
            raise BCBenchError(f"{f} names {n}, which is not a study folder (no spec.json there)")
    left = _left_out_runs(results, spec)
    seen: dict[str, str] = {}
    for n in names:
        for run in sorted((results / n).glob("runs/*/")):
            if run in left:
                continue
            if run.name in seen:  # one model in two studies (a carried-over run) would be read twice
                raise BCBenchError(f"{f}: run {run.name} is in both {seen[run.name]} and {n}; combine studies "
                                   "that share no run, or leave it out of one ('leave_out')")
            seen[run.name] = n
    return spec, left


def _left_out_runs(results: Path, spec: dict[str, Any]) -> set[Path]:
    """The run folders a combined report's `leave_out` names, each by the label its study gives it."""
    f = results / COMBINE_FILE
    leave = spec.get("leave_out", {})
    if not isinstance(leave, dict) or not all(isinstance(v, list) and v and all(isinstance(x, str) for x in v)
                                              for v in leave.values()):
        raise BCBenchError(f"{f}: 'leave_out' must map a study folder it names to a list of run labels")
    out: set[Path] = set()
    for study, labels in leave.items():
        if study not in spec["studies"]:
            raise BCBenchError(f"{f}: 'leave_out' names {study}, which is not one of its studies")
        found = {run: label for run, label in run_labels(results / study).items() if label in labels}
        missing = sorted(set(labels) - set(found.values()))
        if missing:  # a typo would otherwise leave everything in, silently
            raise BCBenchError(f"{f}: {study} has no run labelled {', '.join(map(repr, missing))} to leave out")
        out |= set(found)
    return out


def preset_choices(results: Path) -> list[str]:
    """A combined report's `chosen_by`: for each policy label, the study that chose its preset and the episode seeds
    that study read (issue 30: every choice is made on validation seeds, and the report says where). Empty for a
    study's own folder or a combine.json without it; a label no study of the report trains is refused (a typo
    would otherwise print a choice for nothing)."""
    results = Path(results)
    f = results / COMBINE_FILE
    spec = combined(results)
    chosen = (spec or {}).get("chosen_by", {})
    if not isinstance(chosen, dict) or not all(isinstance(v, str) and v.strip() for v in chosen.values()):
        raise BCBenchError(f"{f}: 'chosen_by' must map a policy label to the study that chose its preset")
    if not chosen:
        return []
    labels = {label for d in _dirs(results, spec) for label in run_labels(d).values()}  # spec read once, above
    unknown = sorted(set(chosen) - labels)
    if unknown:
        raise BCBenchError(f"{f}: 'chosen_by' names {', '.join(map(repr, unknown))}, which no study it combines trains")
    return [f"Preset of {label}: {text}" for label, text in chosen.items()]


def test_informed(results: Path) -> list[dict[str, str]]:
    """The decisions behind a report that a test-seed result informed (the protocol's exceptions): a study folder's
    own (spec.json's `test_informed`), or a combined report's `test_informed`, which must list every decision each
    of its studies records, each naming what it is `about` (a preset's label or a stage). A combined report that
    leaves one out is refused: its Provenance would hide a deviation its own studies state."""
    results = Path(results)
    spec = combined(results)
    if spec is None:
        own = read_json(results / "spec.json").get("test_informed", []) if (results / "spec.json").exists() else []
        return test_informed_entries(own, f"{results / 'spec.json'}: 'test_informed'")
    f = results / COMBINE_FILE
    listed = test_informed_entries(spec.get("test_informed", []), f"{f}: 'test_informed'", ("about",))
    decisions = {e["decision"] for e in listed}
    for n in spec["studies"]:
        own = test_informed_entries(read_json(results / n / "spec.json").get("test_informed", []),
                                    f"{results / n / 'spec.json'}: 'test_informed'")
        missing = [e["decision"] for e in own if e["decision"] not in decisions]
        if missing:
            raise BCBenchError(f"{f}: {n} records {len(missing)} decision(s) a test-seed result informed that its "
                               f"'test_informed' does not list (first: {missing[0][:80]!r}); list each, so the "
                               "report names it")
    return listed


def informed_sentence(informed: list[str]) -> str:
    """The line a report heads with when `informed` (test_informed_lines) is not empty: the brief's rule that a report
    says so itself where a test score informed a decision, not only a study file."""
    return (f"Against the protocol, {len(informed)} decision(s) behind these presets or stages were informed by a "
            "test-seed result; each is listed under Provenance, with the file it read.")


def test_informed_lines(results: Path) -> list[str]:
    """Provenance's lines for `test_informed`, one a decision."""
    return [f"Informed by a test-seed result, against the protocol ({e.get('about', results.name)}): {e['decision']} "
            f"(read: {e['read']})" for e in test_informed(results)]


def run_labels(study: Path) -> dict[Path, str]:
    """Run folder -> its label: the part its study's spec gives it, else the label its own result files record."""
    roles = study_roles(study)
    out = {}
    for run in sorted(study.glob("runs/*/")):
        if run.name in roles:
            out[run] = roles[run.name]["label"]
            continue
        rec = next((read_json(f) for f in sorted(run.glob("*.json")) if f.name.startswith(("eval", "check"))), {})
        if rec.get("study", {}).get("label"):
            out[run] = rec["study"]["label"]
    return out


def study_dirs(results: Path) -> list[Path]:
    """The study folders a report reads: the folder itself, or each folder a combined report names."""
    return _dirs(Path(results), combined(results))


def _dirs(results: Path, spec: dict[str, Any] | None) -> list[Path]:
    return [results / n for n in spec["studies"]] if spec else [results]


def left_out(results: Path) -> dict[str, list[str]]:
    """A combined report's `leave_out` (study folder name -> run labels); empty for a study's own folder."""
    spec = combined(Path(results))
    return {Path(k).name: v for k, v in (spec or {}).get("leave_out", {}).items()}


def left_out_runs(results: Path) -> set[Path]:
    """The run folders a combined report leaves out; empty for a study's own folder."""
    return _combination(Path(results))[1]


def study_files(results: str | Path, pattern: str) -> list[tuple[Path, Path]]:
    """(study folder, file) for each file matching `pattern` under the studies a report reads, less the runs a
    combined report leaves out; sorted within each study."""
    spec, skip = _combination(Path(results))  # read once: it globs and reads every run's files
    return [(d, f) for d in _dirs(Path(results), spec) for f in sorted(d.rglob(pattern))
            if not skip.intersection(f.parents)]


def run_files(results: str | Path, pattern: str) -> list[tuple[Path, Path]]:
    """`study_files` less a report folder's copies inside a study (its own report/ holds no result file)."""
    return [(d, f) for d, f in study_files(results, pattern) if "report" not in f.relative_to(d).parts]


def study_spec(results: Path) -> dict[str, Any]:
    """The study's spec.json; for a combined report, the margin, purpose, task and control rate its studies share
    (they must: one rule judges every finding, on one task; studies of several tasks are read side by side by a
    report across tasks, `bcbench.analysis.across`)."""
    specs = [read_json(d / "spec.json") if (d / "spec.json").exists() else {} for d in study_dirs(results)]
    if len(specs) == 1:
        return specs[0]
    for s in specs:  # a study from before tasks existed ran Push-T at 10 Hz
        s.setdefault("task", "pusht")
        s["rate_hz"] = float(s.get("rate_hz", 10.0))
    for key in ("margin", "purpose", "task", "rate_hz"):
        if len({str(s.get(key)) for s in specs}) > 1:
            raise BCBenchError(f"{results}: its studies differ in {key} ({', '.join(str(s.get(key)) for s in specs)}); "
                               "a combined report needs one" + (" (a report across tasks reads several: across.json)"
                                                                if key == "task" else ""))
    return {k: specs[0].get(k) for k in ("margin", "purpose", "task", "rate_hz")}


def mixing_reason(results: Path) -> str:
    """Why the result files carry several commits, as each study folder (and a combined report's own) records it."""
    dirs = dict.fromkeys([results, *study_dirs(results)])
    found = [(d, d / MIXING_REASON) for d in dirs if (d / MIXING_REASON).exists()]
    texts = [(d.name, " ".join(f.read_text().split())) for d, f in found]
    return texts[0][1] if len(dirs) == 1 and texts else " ".join(f"{name}: {text}" for name, text in texts)


def study_roles(results: Path) -> dict[str, dict[str, Any]]:
    """Run folder -> {label, doubles} as the study's own spec.json names the run.

    A run carried over from another study (the same run key: policy, preset, seed and overrides, so the same model)
    keeps that study's label in its evaluation files; here it plays the part this study's spec gives it, e.g. the
    first round's twice-the-steps run as the second round's seed 0, the base of the next check. A folder that
    matches no spec run, or several, keeps its files' own label."""
    spec_file = results / "spec.json"
    if not spec_file.exists():
        return {}
    runs = read_json(spec_file).get("runs", [])
    roles = {}
    for run_json in results.glob("runs/*/run.json"):
        meta = read_json(run_json)
        same = [r for r in runs if r.get("policy") == meta.get("policy") and r.get("config") == meta.get("preset")
                and {**(r.get("overrides") or {}), "seed": r.get("seed")} == (meta.get("overrides") or {})]
        if len(same) == 1:
            roles[run_json.parent.name] = {"label": same[0]["label"], "doubles": same[0].get("doubles")}
    return roles
