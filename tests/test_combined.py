"""A combined report (combine.json): one report over several study folders, e.g. issue 30's confirm stages, each run
playing the part its own study's spec gives it, its checks read from its own folder."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from bcbench.analysis.report import write_report
from bcbench.analysis.results import load_check_rows, load_rows
from bcbench.analysis.studies import study_dirs
from bcbench.errors import BCBenchError
from bcbench.utils.io import write_json
from tests.test_seeds import _eval

EPISODES = 100


def _stage(root: Path, name: str, policies: dict[str, tuple[str, float]], commit: str, margin: float = 0.05) -> Path:
    """One confirm study folder: each label trained with 3 seeds (test seeds) and seed 0 checked against a
    doubling run on 60 validation episodes that scores the same."""
    d = root / name
    rng = np.random.default_rng(len(name))
    write_json(d / "spec.json", {"purpose": "confirm", "margin": margin, "runs": []})
    for label, (policy, mean) in policies.items():
        for s in range(3):
            rec = _eval(policy, label, np.clip(mean + rng.normal(0, 0.1, EPISODES), 0, 1), s, f"{label}-s{s}")
            write_json(d / "runs" / f"{label}-s{s}" / "eval-default.json", {**rec, "git_commit": commit})
        val = np.clip(mean + rng.uniform(-0.2, 0.2, 60), 0, 1)
        for run, lab, doubles in ((f"{label}-s0", label, None), (f"{label}-2x", f"{label} 2x", label)):
            rec = _eval(policy, lab, val, 0, run, start=200_000)
            rec["study"].update({"check": True, **({"doubles": doubles} if doubles else {})})
            write_json(d / "runs" / run / "check-default.json", {**rec, "git_commit": commit})
    (d / "mixing-reason.txt").write_text(f"why {name}\n")
    return d


def _combined(tmp_path: Path, margin: float = 0.05) -> Path:
    _stage(tmp_path, "stage-a", {"ResNet-50": ("resnet50", 0.6)}, "a" * 40)
    _stage(tmp_path, "stage-b", {"BCT": ("bct", 0.45), "CNN-MLP": ("cnn_mlp", 0.2)}, "b" * 40, margin)
    write_json(tmp_path / "all" / "combine.json", {"studies": ["../stage-a", "../stage-b"], "why": "one report"})
    return tmp_path / "all"


def test_a_combined_report_reads_every_study_and_its_checks(tmp_path):
    out = _combined(tmp_path)
    assert [d.name for d in study_dirs(out)] == ["stage-a", "stage-b"]
    assert sorted({r.label for r in load_rows(out)}) == ["BCT", "CNN-MLP", "ResNet-50"]
    assert len(load_check_rows(out)) == 6  # each label's seed 0 and its doubling run, from its own folder
    md = Path(write_report(out)["markdown"]).read_text()
    assert md.startswith("# bcbench report\n\nStudy `all (combines stage-a, stage-b)`")
    for label in ("ResNet-50", "BCT", "CNN-MLP"):  # every label judged by its own study's check
        assert f"| {label} | DEFAULT (of 1) | +0.000 [+0.000, +0.000] | 60 | **converged** |" in md, label
    provenance = md.split("## Provenance")[1]
    assert "aaaaaaaaaaaa" in provenance and "bbbbbbbbbbbb" in provenance  # both studies' commits, with the warning
    assert "stage-a: why stage-a stage-b: why stage-b" in provenance
    # a study's own interleaved timing is not read by the combined report, so its commit is not named
    write_json(tmp_path / "stage-a" / "latency-paired.json", {"type": "latency-paired", "git_commit": "c" * 40})
    assert "cccccccccccc" not in Path(write_report(out)["markdown"]).read_text()


def test_a_combined_report_refuses_a_missing_study_or_two_margins(tmp_path):
    out = _combined(tmp_path)
    write_json(out / "combine.json", {"studies": ["../stage-a", "../nowhere"]})
    with pytest.raises(BCBenchError, match=re.escape("names ../nowhere, which is not a study folder")):
        write_report(out)
    (out / "combine.json").write_text(json.dumps({"studies": []}))
    with pytest.raises(BCBenchError, match="must list the study folders"):
        write_report(out)
    write_json(out / "combine.json", {"studies": ["../stage-a", "../stage-a"]})
    with pytest.raises(BCBenchError, match=re.escape("is in both ../stage-a and ../stage-a")):
        write_report(out)
    out2 = _combined(tmp_path / "m", margin=0.1)
    with pytest.raises(BCBenchError, match="differ in margin"):
        write_report(out2)


def test_a_combined_report_names_the_study_that_chose_each_preset(tmp_path):
    """Issue 30: the report names, for every preset, the study that chose it and the seeds it read (combine.json's
    `chosen_by`, printed under Provenance); a label no combined study trains, or an empty text, is refused."""
    out = _combined(tmp_path)
    spec = {"studies": ["../stage-a", "../stage-b"], "why": "one report",
            "chosen_by": {"BCT": "chosen by explore-x (validation seeds 200000-200049)",
                          "ResNet-50": "chosen by explore-y"}}
    write_json(out / "combine.json", spec)
    provenance = Path(write_report(out)["markdown"]).read_text().split("## Provenance")[1]
    assert "- Preset of BCT: chosen by explore-x (validation seeds 200000-200049)" in provenance
    assert "- Preset of ResNet-50: chosen by explore-y" in provenance
    assert "Preset of BCT: chosen by explore-x" in Path(out / "report" / "report.html").read_text()
    write_json(out / "combine.json", {**spec, "chosen_by": {"BTC": "explore-x"}})
    with pytest.raises(BCBenchError, match=re.escape("'chosen_by' names 'BTC', which no study it combines trains")):
        write_report(out)
    write_json(out / "combine.json", {**spec, "chosen_by": {"BCT": " "}})
    with pytest.raises(BCBenchError, match="'chosen_by' must map a policy label"):
        write_report(out)


def test_a_combined_report_leaves_out_a_replaced_round(tmp_path):
    """A policy's second round, a study of its own, replaces its first: the rounds share a run folder (the first
    round's doubling run is the second's seed 0) and a label. `leave_out` drops the first round's runs of that label
    from every reader (rows, checks, commits, recorded time), so nothing is counted twice; a label no run has is
    refused, not ignored."""
    from bcbench.analysis.results import file_commits, study_time

    out = _combined(tmp_path)
    _stage(tmp_path, "stage-c", {"ResNet-50": ("resnet50", 0.7)}, "c" * 40)
    assert (tmp_path / "stage-c" / "runs" / "ResNet-50-2x").is_dir()  # a run folder both rounds have
    (tmp_path / "stage-a" / "index.jsonl").write_text(
        json.dumps({"stage": "check", "file": "runs/ResNet-50-s0/check-default.json", "seconds": 60.0}) + "\n"
        + json.dumps({"stage": "check", "file": "runs/BCT/x.json", "seconds": 1.0}) + "\n")
    write_json(out / "combine.json", {"studies": ["../stage-a", "../stage-b", "../stage-c"], "why": "rounds"})
    with pytest.raises(BCBenchError, match=re.escape("run ResNet-50-2x is in both ../stage-a and ../stage-c")):
        load_rows(out)
    write_json(out / "combine.json", {"studies": ["../stage-a", "../stage-b", "../stage-c"], "why": "rounds",
                                      "leave_out": {"../stage-a": ["ResNet-50", "ResNet-50 2x"]}})
    rows = load_rows(out)
    assert sorted({r.label for r in rows}) == ["BCT", "CNN-MLP", "ResNet-50"]
    assert {r.git_commit for r in rows if r.label == "ResNet-50"} == {"c" * 40}  # the second round's only
    assert "a" * 40 not in file_commits(out)
    assert study_time(out)["evaluation"] == 1.0  # stage-a's left-out check is not recorded time
    md = Path(write_report(out)["markdown"]).read_text()
    assert "combines stage-a, stage-b, stage-c; leaves out 'ResNet-50' and 'ResNet-50 2x' of stage-a)" in md
    write_json(out / "combine.json", {"studies": ["../stage-a", "../stage-b", "../stage-c"],
                                      "leave_out": {"../stage-a": ["ResNet50"]}})
    with pytest.raises(BCBenchError, match=re.escape("../stage-a has no run labelled 'ResNet50' to leave out")):
        load_rows(out)
    write_json(out / "combine.json", {"studies": ["../stage-a"], "leave_out": {"../stage-z": ["BCT"]}})
    with pytest.raises(BCBenchError, match=re.escape("'leave_out' names ../stage-z, which is not one of its")):
        load_rows(out)


def test_a_combined_report_is_not_exported(tmp_path, capsys):
    """Its studies are exported one by one (each can be restored and resumed); the CLI says so in one line."""
    from bcbench.cli.main import main

    out = _combined(tmp_path)
    assert main(["report", str(out), "--export", str(tmp_path / "exp")]) != 0
    assert not (tmp_path / "exp").exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a combined report (combine.json): export each study it names" in err[0]



def test_figure_5_of_a_combined_report_stands_on_its_interleaved_times(tmp_path):
    """Each stage timed its own settings, hours apart; where the combined folder holds an interleaved timing in
    Figure 5's mode, the settings it timed stand at its medians, the rest at their own times, and the axis says so."""
    from bcbench.analysis.accuracy_latency import figure5_times
    from bcbench.analysis.seeds import merge_training_seeds

    out = _combined(tmp_path)
    for label, ms in (("BCT", 9.0), ("CNN-MLP", 4.0)):  # the stages' own timings of seed 0
        write_json(tmp_path / "stage-b" / "runs" / f"{label}-s0" / "latency-default.json",
                   {"modes": {"reference": {"median_ms": ms}, "fast": {"median_ms": ms / 2}}})
    settings = merge_training_seeds(load_rows(out))
    by_label = {r.label: r.key for r in settings}
    own = figure5_times(settings)
    assert own == {by_label["BCT"]: 9.0, by_label["CNN-MLP"]: 4.0}  # ResNet-50 has no time: not on the figure
    timing = {"mode": "reference", "rounds": 10, "median_ms": {"bct": 6.0, "resnet50": 3.0},
              "file": "latency-paired.json"}
    assert figure5_times(settings, timing=timing) == {by_label["BCT"]: 6.0, by_label["CNN-MLP"]: 4.0,
                                                     by_label["ResNet-50"]: 3.0}
    write_json(out / "latency-paired.json", {"type": "latency-paired", "git_commit": "c" * 40, **timing})
    assert (Path(write_report(out)["dir"]) / "fig5_accuracy_vs_latency.png").exists()
    # the arrow to the fastest exact deployed mode: from the interleaved run where it timed the setting, else the
    # row's own ratio (fast / reference = 1/2) applied where the point stands
    from bcbench.analysis.accuracy_latency import _deployed

    bct = next(r for r in settings if r.label == "BCT")
    run = {"reference": timing, "openvino-fp32": {**timing, "median_ms": {"bct": 2.0}}}
    assert _deployed(bct, 6.0, "reference", run) == ("openvino-fp32", 2.0)
    assert _deployed(bct, 6.0, "reference", None) == ("fast", 3.0)
