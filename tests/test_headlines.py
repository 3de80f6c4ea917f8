"""Headlines a skeptical reviewer accepts (issue 74): miniatures named with their size, the weights every record ran
named by their sha256, and every decision a test-seed result informed listed where the report is read."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bcbench.analysis.report import write_report
from bcbench.analysis.results import weights_conflicts
from bcbench.cli.main import main
from bcbench.reference import sized_label
from bcbench.utils.io import read_json, write_json
from tests.test_combined import _combined

ROOT = Path(__file__).resolve().parents[1]
PUBLISHED = sorted(p.parent for p in (ROOT / "models").glob("*/model.json"))
FULL = {"obs_horizon": 2, "pred_horizon": 16}  # what every real config has


@pytest.mark.parametrize("label, policy, params, config, expected", [
    ("ResNet-50 CNN", "resnet50", 486_417, {**FULL, "width": 8, "pretrained": None},
     "ResNet-50 CNN, 1/8 width (0.49 M, random init)"),
    ("ResNet-50 CNN", "resnet50", 34_527_746, {**FULL, "width": 64, "pretrained": "imagenet.pth"}, "ResNet-50 CNN"),
    ("ResNet-50 CNN", "resnet50", 34_527_746, {**FULL, "width": 64, "pretrained": None},
     "ResNet-50 CNN (34.53 M, random init)"),  # the study's size, not its init
    ("BCT", "bct", 1_118_226, {**FULL, "encoder_width": 16}, "BCT, 1/4 width (1.12 M)"),
    ("Diffusion Policy (cosine)", "diffusion", 91_123_778, {**FULL, "encoder_width": 64}, "Diffusion Policy (cosine)"),
    ("Flow matching", "flow", 5_329_490, {**FULL, "encoder_width": 16}, "Flow matching, 1/4 width (5.33 M)"),
    ("CNN-MLP", "cnn_mlp", 1_366_239, {**FULL, "channels": [16, 32]}, "CNN-MLP"),  # the study's network
    ("BeT (chunked)", "bet", 1_199_568, {**FULL, "encoder_width": 16}, "BeT (chunked), 1/4 width (1.20 M)"),
    ("scripted", "scripted", 0, {**FULL}, "scripted"),  # no network to size
    ("knn", "knn", 10, {**FULL}, "knn"),  # a user's policy is shown as given
    ("BCT", "bct", 1000, {"seed": 0}, "BCT"),  # a record without its config: nothing to say
])
def test_a_miniature_is_named_with_its_size_and_init(label, policy, params, config, expected):
    assert sized_label(label, policy, params, config) == expected


def test_the_committed_confirm_report_names_each_miniature_by_its_size():
    md = (ROOT / "results" / "cpu-confirm" / "report" / "report.md").read_text()
    assert "| ResNet-50 CNN, 1/8 width (0.49 M, random init) |" in md
    assert "| ResNet-50 CNN |" not in md and "| BCT |" not in md
    finding4 = next(line for line in md.splitlines() if line.startswith("4. **ResNet-50 > BCT"))
    assert "At these sizes, not the study's networks" in finding4


@pytest.mark.parametrize("model_dir", PUBLISHED, ids=[p.name for p in PUBLISHED])
def test_a_record_names_the_sha256_of_the_published_weights_it_ran(model_dir):
    from bcbench.policies.checkpoint import load_runner
    from bcbench.utils.io import sha256_file

    described = load_runner(model_dir).describe()  # what every evaluation, latency, tiers and real-time record holds
    record = read_json(model_dir / "model.json")
    assert described["weights_sha256"] == record["file"]["sha256"]
    assert described["normalizer_sha256"] == sha256_file(model_dir / "normalizer.json")


def _with_weights(study: Path, run: str, sha: str, name: str) -> None:
    f = study / "runs" / run / name
    rec = read_json(f)
    rec["policy"].update({"run_dir": f"/x/{run}", "checkpoint": "step_0000010", "weights": "ema",
                          "weights_sha256": sha})
    write_json(f, rec)


def test_a_report_warns_when_one_runs_records_name_two_weights_files(tmp_path, capsys):
    out = _combined(tmp_path)
    stage = tmp_path / "stage-a"
    _with_weights(stage, "ResNet-50-s0", "a" * 64, "eval-default.json")
    _with_weights(stage, "ResNet-50-s0", "a" * 64, "check-default.json")
    assert weights_conflicts(out) == []  # one model, however many records
    _with_weights(stage, "ResNet-50-s0", "b" * 64, "check-default.json")  # the folder's weights were replaced
    warnings = weights_conflicts(out)
    assert len(warnings) == 1 and "ResNet-50-s0" in warnings[0] and "aaaaaaaaaaaa" in warnings[0]
    assert main(["report", str(out)]) == 0
    assert "ResNet-50-s0 (step_0000010, ema weights) name 2 different weights files" in capsys.readouterr().err
    assert warnings[0] in (out / "report" / "report.md").read_text().split("## Provenance")[1]


def test_a_combined_report_lists_every_test_informed_decision_its_studies_record(tmp_path, capsys):
    out = _combined(tmp_path)
    spec = read_json(tmp_path / "stage-b" / "spec.json")
    decision = {"decision": "seeds 1-2 added after a test-seed comparison", "read": "runs/BCT-s0/eval-default.json"}
    write_json(tmp_path / "stage-b" / "spec.json", {**spec, "test_informed": [decision]})
    assert main(["report", str(out)]) == 2  # combine.json does not list it
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "../stage-b records 1 decision(s) a test-seed result informed" in err
    combine = read_json(out / "combine.json")
    write_json(out / "combine.json", {**combine, "test_informed": [decision]})  # no 'about': refused too
    assert main(["report", str(out)]) == 2
    assert "about" in capsys.readouterr().err
    write_json(out / "combine.json", {**combine, "test_informed": [{**decision, "about": "BCT"}]})
    md = Path(write_report(out)["markdown"]).read_text()
    line = ("Informed by a test-seed result, against the protocol (BCT): seeds 1-2 added after a test-seed "
            "comparison (read: runs/BCT-s0/eval-default.json)")
    assert f"- {line}" in md.split("## Provenance")[1]
    assert "1 decision(s) behind these presets or stages were informed by a test-seed result" in md.split(
        "## The study's findings")[0]  # said beside the answer, not only at the end
    assert json.dumps(line)[1:-1] in (out / "report" / "report.html").read_text() or line in (
        out / "report" / "report.html").read_text().replace("&#x27;", "'")


def test_the_committed_confirm_report_prints_its_test_informed_decisions():
    combine = read_json(ROOT / "results" / "cpu-confirm" / "combine.json")
    provenance = (ROOT / "results" / "cpu-confirm" / "report" / "report.md").read_text().split("## Provenance")[1]
    assert len(combine["test_informed"]) >= 5
    for e in combine["test_informed"]:
        assert e["decision"] in provenance


# a sentence that says a strategy keeps or recovers a score (issue 74: it names the training seeds it rests on)
CLAIM = re.compile(r"keeps (its|the) sync score|gets back [0-9]+%|recovers [0-9]+%|takes back [0-9]+%")


def test_every_real_time_claim_says_how_many_trained_models_it_rests_on():
    for doc in ("README.md", "docs/realtime.md", "docs/results.md"):
        for n, line in enumerate((ROOT / doc).read_text().splitlines(), 1):
            if CLAIM.search(line):
                assert "training seed" in line, f"{doc}:{n}: {line}"


def _recovery(policy: str, d: int, naive: str, at_horizon: str, strategy: str) -> dict[str, str]:
    """scripts/recovery.py's three steps over the committed replicates: {"loss", "step1", "step2", "total"}, each the
    text a reader would quote (a difference and its interval, or a share and its interval)."""
    r = ROOT / "results" / "strategies-replicates" / policy
    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "recovery.py"),
                          "--sync", f"{r}/seed*/naive-d8/realtime-sync.json",
                          "--naive", f"{r}/seed*/{naive}/realtime-async-d{d}.json",
                          "--naive-at-horizon", f"{r}/seed*/{at_horizon}/realtime-async-d{d}.json",
                          f"{r}/seed*/{strategy}/realtime-async-d{d}.json"],
                         capture_output=True, text=True, check=True).stdout
    interval, share = r"[+-]\d\.\d{3} \[[+-]\d\.\d{3}, [+-]\d\.\d{3}\]", r"-?\d+% \[-?\d+, -?\d+\]"
    lines = out.splitlines()
    loss = re.search(rf"({interval}) against sync", lines[1])
    step1, step2, total = lines[2], lines[3], lines[4]
    return {"loss": loss.group(1),
            "step1_sync": re.search(rf"({interval}) against sync", step1).group(1),
            "step1_share": re.search(rf"({share}) of naive's loss", step1).group(1),
            "step2": re.search(rf"({interval}) over the step before", step2).group(1),
            "step2_share": re.search(rf"({share}) of naive's loss", step2).group(1),
            "total_sync": re.search(rf"({interval}) against sync", total).group(1),
            "total_share": re.search(rf"({share}) of naive's loss", total).group(1)}


def test_the_readmes_real_time_numbers_regenerate_with_their_horizon_split():
    """The README's d = 4 retention and d = 8 recoveries, each split into the horizon's step and the method's, are what
    scripts/recovery.py computes from the committed replicate records."""
    readme = " ".join((ROOT / "README.md").read_text().split())
    dp4 = _recovery("dp-ddim10", 4, "naive-d4", "naive-d4-s8", "rtc-d4/rtc")
    for key in ("loss", "step1_sync", "step2", "total_sync"):
        assert dp4[key] in readme, (key, dp4[key])
    for policy in ("dp-ddim10", "flow-euler10"):
        d8 = _recovery(policy, 8, "naive-d8", "naive-d8-s7", "rtc-d8/rtc")
        for key in ("step1_share", "step2_share", "total_share"):
            assert d8[key] in readme, (policy, key, d8[key])
    assert "one trained model per policy (training seed 0) with 3 noise replicates" in readme
